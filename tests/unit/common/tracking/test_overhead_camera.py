"""The independent renderer (tests/kit/overhead_camera.py) draws what its textbook model says:
its projection is OpenCV's, and the markers appear where it projects them."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from common.tracking.markers import MarkerLayout, corners_mm, default_layout, dictionary
from tests.kit.overhead_camera import Lens, Mount, OverheadCamera, Robot

# Making the module's camera costs seconds of CPU: its tests share one
# worker (xdist group), which makes it once.
pytestmark = pytest.mark.one_worker


@pytest.fixture(scope="module")
def layout() -> MarkerLayout:
    return default_layout(1000, 1000, ["k1", "k2"])


@pytest.fixture(scope="module")
def camera(layout: MarkerLayout) -> OverheadCamera:
    return OverheadCamera(
        1000, 1000, layout, Lens(k1=0.12, k2=-0.02), Mount(tilt_deg=22, roll_deg=-3)
    )


def test_its_projection_is_the_pinhole_model_opencv_documents(camera: OverheadCamera) -> None:
    points = np.array([[0, 0, 0], [1000, 0, 0], [1000, 1000, 40], [250, 700, 10]], float)
    rvec, _ = cv2.Rodrigues(camera.rotation)
    tvec = -camera.rotation @ camera.centre
    theirs, _ = cv2.projectPoints(points, rvec, tvec, camera.lens.matrix, camera.lens.coefficients)
    assert np.abs(theirs.reshape(-1, 2) - camera.project(points)).max() < 1e-6
    ideal = np.array([[0.2, -0.1], [-0.3, 0.25]])
    assert np.allclose(camera.lens.undistort(camera.lens.distort(ideal)), ideal, atol=1e-9)


def test_markers_are_drawn_where_it_projects_them(
    camera: OverheadCamera, layout: MarkerLayout
) -> None:
    robots = {"k1": Robot(300.0, 620.0, 0.4), "k2": Robot(720.0, 300.0, -2.2)}
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    found, ids, _ = cv2.aruco.ArucoDetector(dictionary(), params).detectMarkers(
        cv2.cvtColor(camera.render(robots), cv2.COLOR_BGR2GRAY)
    )
    seen = {int(i): c.reshape(4, 2) for i, c in zip(ids.ravel(), found, strict=True)}
    assert sorted(seen) == sorted([*layout.reference, *layout.robots.values()])
    floor = np.vstack(
        [
            seen[i] - camera.project(np.column_stack([corners_mm(x, y, np.pi / 2, 50.0), [0] * 4]))
            for i, (x, y) in layout.reference.items()
        ]
    )
    # Corners to a fraction of a pixel on markers 20 to 30 px wide, blurred, noisy, JPEG.
    assert np.abs(floor).max() < 0.8
    assert float(np.mean(np.linalg.norm(floor, axis=1))) < 0.4
    for agent, r in robots.items():
        # A robot's marker (its quiet zone one cell, the dark body beyond): its centre.
        top = np.column_stack([corners_mm(r.x, r.y, r.heading, 40.0), [40.0] * 4])
        centre = seen[layout.robots[agent]].mean(axis=0) - camera.project(top).mean(axis=0)
        assert np.linalg.norm(centre) < 0.5, agent


def test_a_fast_robot_is_smeared_along_its_motion(camera: OverheadCamera) -> None:
    still = camera.render({"k1": Robot(500.0, 500.0, 0.0)})
    moving = camera.render({"k1": Robot(500.0, 500.0, 0.0, vx=600.0)})
    row = int(camera.project(np.array([[500.0, 500.0, 40.0]]))[0, 1])
    edges = [np.abs(np.diff(f[row, :, 0].astype(int))).max() for f in (still, moving)]
    assert edges[1] < edges[0] / 2
