"""The README's clip of the demo: an animated GIF cut from ``out/demo/demo.mp4`` (``make demo``).

Usage::

    .venv/bin/python bench/make_demo_gif.py [--video out/demo/demo.mp4] [--out docs/img/demo_round.gif]
        [--start 0] [--seconds 14] [--fps 5] [--width 400]

Decodes the H.264 mosaic with PyAV, keeps ``--fps`` frames a second from ``--start`` for
``--seconds``, scales them to ``--width`` and writes a looping GIF with Pillow (one adaptive
palette per frame). GIFs only where a README embeds them; every other video is H.264.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import av
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", default=str(ROOT / "out" / "demo" / "demo.mp4"))
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "demo_round.gif"))
    ap.add_argument("--start", type=float, default=0.0, help="seconds into the video")
    ap.add_argument("--seconds", type=float, default=14.0)
    ap.add_argument("--fps", type=float, default=5.0)
    ap.add_argument("--width", type=int, default=400)
    args = ap.parse_args()
    frames: list[Image.Image] = []
    with av.open(args.video) as container:
        stream = container.streams.video[0]
        next_t = args.start
        for frame in container.decode(stream):
            t = float(frame.pts * stream.time_base) if frame.pts is not None else 0.0
            if t < next_t - 1e-6:
                continue
            if t > args.start + args.seconds:
                break
            img = frame.to_image()
            h = round(img.height * args.width / img.width)
            frames.append(img.resize((args.width, h), Image.Resampling.LANCZOS).convert(
                "P", palette=Image.Palette.ADAPTIVE, colors=64))
            next_t += 1.0 / args.fps
    if not frames:
        raise SystemExit(f"{args.video}: no frames between {args.start} s and {args.start + args.seconds} s")
    frames[0].save(args.out, save_all=True, append_images=frames[1:], duration=round(1000 / args.fps), loop=0,
                   optimize=True)
    print(f"wrote {args.out}: {len(frames)} frames, {Path(args.out).stat().st_size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
