"""OpenCV's semi-global matcher on rectified neighbour pairs, for `cargo xtask bench dense`.

Input: a views.json written by the bench (per view: undistorted grey image, pinhole camera f,
cx, cy in the docs/design.md pixel convention, pose cam_from_local R, t, the best source view, the
depth range). For each view with a source: stereo rectification of the pair (the left image is
the one whose camera lies to the left), StereoSGBM over the disparity range the depth range
allows, left-right check and speckle filter built into SGBM, triangulation of every valid
disparity into the local frame. Output: every point as little-endian float64 x, y, z in
`out`, and a JSON line {"seconds": ..., "points": ..., "pairs": ...} on stdout; the time covers
reading the images, rectification, matching and triangulation.

usage: opencv_sgbm.py views.json out.bin threads
"""
import json
import sys
import time

import cv2
import numpy as np


def camera_matrix(v):
    # docs/design.md: pixel centres at i + 0.5; OpenCV: at i.
    return np.array([[v["f"], 0.0, v["cx"] - 0.5], [0.0, v["f"], v["cy"] - 0.5], [0.0, 0.0, 1.0]])


def main():
    views_path, out_path, threads = sys.argv[1], sys.argv[2], int(sys.argv[3])
    cv2.setNumThreads(threads)
    views = json.load(open(views_path))["views"]
    start = time.perf_counter()
    clouds = []
    pairs = 0
    for ref in views:
        s = ref.get("source")
        if s is None:
            continue
        src = views[s]
        R1w, t1w = np.array(ref["R"]), np.array(ref["t"])
        R2w, t2w = np.array(src["R"]), np.array(src["t"])
        # Source camera centre in the reference frame: which one is left.
        c2 = -R2w.T @ t2w
        c2_in_ref = R1w @ c2 + t1w
        left, right = (ref, src) if c2_in_ref[0] > 0 else (src, ref)
        RL, tL = np.array(left["R"]), np.array(left["t"])
        RR, tR = np.array(right["R"]), np.array(right["t"])
        R = RR @ RL.T  # right_from_left
        T = tR - R @ tL
        KL, KR = camera_matrix(left), camera_matrix(right)
        size = (left["width"], left["height"])
        imL = cv2.imread(left["image"], cv2.IMREAD_GRAYSCALE)
        imR = cv2.imread(right["image"], cv2.IMREAD_GRAYSCALE)
        if imR.shape[::-1] != size:
            imR = cv2.resize(imR, size)
            KR = KR.copy()
        no_distortion = np.zeros(5)
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            KL,
            no_distortion,
            KR,
            no_distortion,
            size,
            np.ascontiguousarray(R),
            T.reshape(3, 1),
            flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=-1,
        )
        m1 = cv2.initUndistortRectifyMap(KL, no_distortion, R1, P1, size, cv2.CV_32FC1)
        m2 = cv2.initUndistortRectifyMap(KR, no_distortion, R2, P2, size, cv2.CV_32FC1)
        rl = cv2.remap(imL, m1[0], m1[1], cv2.INTER_LINEAR)
        rr = cv2.remap(imR, m2[0], m2[1], cv2.INTER_LINEAR)
        f = P1[0, 0]
        baseline = abs(P2[0, 3] / P2[0, 0])
        dmin, dmax = ref["depth_range"]
        lo = max(0, int(np.floor(f * baseline / dmax)) - 2)
        hi = int(np.ceil(f * baseline / max(dmin, 1e-6))) + 2
        num = int(min(16 * np.ceil((hi - lo) / 16.0), 512))
        # SGBM needs width − (minDisparity + numDisparities) > blockSize / 2.
        block = 5
        num = min(num, int((size[0] - lo - block // 2 - 1) // 16) * 16)
        if num < 16:
            continue
        sgbm = cv2.StereoSGBM_create(
            minDisparity=lo,
            numDisparities=num,
            blockSize=block,
            P1=8 * block * block,
            P2=32 * block * block,
            disp12MaxDiff=1,
            uniquenessRatio=10,
            speckleWindowSize=100,
            speckleRange=2,
            mode=cv2.STEREO_SGBM_MODE_SGBM,
        )
        disparity = sgbm.compute(rl, rr).astype(np.float32) / 16.0
        valid = disparity > lo
        points = cv2.reprojectImageTo3D(disparity, Q)
        points = points[valid]
        points = points[np.isfinite(points).all(axis=1) & (points[:, 2] > 0)]
        # Rectified left frame -> left camera frame -> local frame.
        x_left = points @ R1  # R1ᵀ applied to each row
        x_local = (x_left - tL) @ RL  # RLᵀ (x − t)
        clouds.append(x_local)
        pairs += 1
    seconds = time.perf_counter() - start
    cloud = np.concatenate(clouds) if clouds else np.zeros((0, 3))
    cloud.astype("<f8").tofile(out_path)
    print(json.dumps({"seconds": seconds, "points": int(cloud.shape[0]), "pairs": pairs}))


if __name__ == "__main__":
    main()
