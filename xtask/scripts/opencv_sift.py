#!/usr/bin/env python3
"""OpenCV SIFT as the peer of timesift's features benchmark.

Usage:
  python3 opencv_sift.py quality --budget N --out DIR IMAGE:MASK ...
      Writes DIR/<image stem>.txt in timesift's feature text format (docs/design.md): first line
      "N 128", then "x y scale orientation d1..d128" with x, y in timesift's pixel convention
      (OpenCV's pixel centres are integers, timesift's are at +0.5), scale = OpenCV size / 2,
      orientation in radians. Masks are grey images, non-zero = keypoints allowed.
  python3 opencv_sift.py speed --budget N --threads T IMAGE ...
      Prints one JSON line: seconds per image (grey decoding + detectAndCompute, after one
      warm-up image) and mean keypoints per image.
"""
import argparse
import json
import os
import sys
import time

import cv2
import numpy as np


def quality(args):
    sift = cv2.SIFT_create(nfeatures=args.budget)
    counts = {}
    for pair in args.images:
        image_path, mask_path = pair.split(":")
        image = cv2.imread(image_path, cv2.IMREAD_GRAYSCALE)
        mask = cv2.imread(mask_path, cv2.IMREAD_GRAYSCALE)
        keypoints, descriptors = sift.detectAndCompute(image, mask)
        stem = os.path.splitext(os.path.basename(image_path))[0]
        with open(os.path.join(args.out, stem + ".txt"), "w") as f:
            f.write(f"{len(keypoints)} 128\n")
            for k, d in zip(keypoints, descriptors if descriptors is not None else []):
                values = " ".join(f"{v:g}" for v in d)
                f.write(
                    f"{k.pt[0] + 0.5} {k.pt[1] + 0.5} {k.size / 2} {np.deg2rad(k.angle)} {values}\n"
                )
        counts[stem] = len(keypoints)
    print(json.dumps({"keypoints": counts, "version": cv2.__version__}))


def speed(args):
    cv2.setNumThreads(args.threads)
    sift = cv2.SIFT_create(nfeatures=args.budget)
    warm = cv2.imread(args.images[0], cv2.IMREAD_GRAYSCALE)
    sift.detectAndCompute(warm, None)
    total = 0
    start = time.perf_counter()
    for path in args.images:
        image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        keypoints, _ = sift.detectAndCompute(image, None)
        total += len(keypoints)
    seconds = time.perf_counter() - start
    print(
        json.dumps(
            {
                "seconds_per_image": seconds / len(args.images),
                "keypoints": total / len(args.images),
                "version": cv2.__version__,
            }
        )
    )


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("mode", choices=["quality", "speed"])
    parser.add_argument("--budget", type=int, required=True)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default=".")
    parser.add_argument("images", nargs="+")
    args = parser.parse_args()
    if args.mode == "quality":
        quality(args)
    else:
        speed(args)


if __name__ == "__main__":
    sys.exit(main())
