"""Write the rendered camera frame nearest to a time from a run's log.

    python tools/extract_frame.py runs/<log>.mcap --t 4.0 --out docs/images/camera_frame.jpg
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from fwsim.interface import topics
from fwsim.log import read_log


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--t", type=float, required=True, help="sim time, s")
    ap.add_argument("--out", required=True)
    ap.add_argument("--topic", default=topics.CAMERA_IMAGE)
    args = ap.parse_args(argv)
    log = read_log(args.log)
    if args.topic not in log.topics:
        print(f"{args.log}: no {args.topic} topic (renders off?)", file=sys.stderr)
        return 1
    ns, data = min(log.raw(args.topic), key=lambda m: abs(m[0] * 1e-9 - args.t))
    img = CompressedImage()
    img.ParseFromString(data)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_bytes(img.data)
    print(f"frame at t = {ns * 1e-9:.2f} s -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
