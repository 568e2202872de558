"""OpenCV's SimpleBlobDetector as the peer of `deltaz bench-measure`.

Usage: python3 opencv_peer.py IMAGE REPEATS
Prints the best time (seconds) of REPEATS detections, then one "col row" line per keypoint.
"""
import sys
import time

import cv2

image = cv2.imread(sys.argv[1], cv2.IMREAD_GRAYSCALE)
params = cv2.SimpleBlobDetector_Params()
params.blobColor = 255
params.minArea = 10
params.maxArea = 5000
detector = cv2.SimpleBlobDetector_create(params)
best = float("inf")
for _ in range(max(1, int(sys.argv[2]))):
    start = time.perf_counter()
    keypoints = detector.detect(image)
    best = min(best, time.perf_counter() - start)
print(best)
for k in keypoints:
    print(k.pt[0], k.pt[1])
