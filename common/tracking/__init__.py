"""Overhead tracking of marked robots: markers, calibration, the tracker, a synthetic camera.

A library with no network in it (like sim2d/): the camera service runs it on
each captured frame, tests and the bench run it on frames the synthetic camera
renders from known poses. Detection is OpenCV's ArUco detector; the floor is
mapped to the arena by a homography from reference markers at known points.
"""
