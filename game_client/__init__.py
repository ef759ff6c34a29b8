"""The ninja game front-end: recognises five body gestures from the tracker's pose stream."""
