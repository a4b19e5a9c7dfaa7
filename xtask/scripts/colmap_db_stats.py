#!/usr/bin/env python3
"""Statistics of a COLMAP database after feature extraction and matching, as one JSON line:
images, mean keypoints, pairs with raw matches, verified pairs (two-view geometries with
inliers) and their median inlier count.

Usage: python3 colmap_db_stats.py DATABASE
"""
import json
import sqlite3
import statistics
import sys

db = sqlite3.connect(sys.argv[1])
keypoints = [r[0] for r in db.execute("select rows from keypoints")]
raw = [r[0] for r in db.execute("select rows from matches")]
verified = [r[0] for r in db.execute("select rows from two_view_geometries") if r[0] > 0]
print(
    json.dumps(
        {
            "images": len(keypoints),
            "keypoints": statistics.mean(keypoints) if keypoints else 0,
            "pairs_with_matches": sum(1 for r in raw if r > 0),
            "verified_pairs": len(verified),
            "median_inliers": statistics.median(verified) if verified else 0,
        }
    )
)
