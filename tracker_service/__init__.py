"""The tracker service: from camera frames to 3D poses published over Zenoh (Okada & Stenger's
tree-based filter and the other estimators), plus the replay publisher and the evaluation tools."""
