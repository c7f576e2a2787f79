"""The bridge's pose of a real robot: the camera's sightings correct its drifting odometry."""

from __future__ import annotations

import itertools
import math

import msgspec
import pytest

from common.messages import MessageError, TrackedPoses, decode, encode
from common.tracking.fusion import CameraClock, PoseFusion


def drive(
    fusion: PoseFusion, seconds: float, *, camera_every: float | None, slip: float
) -> list[float]:
    """A robot driving a circle; its odometry overestimates each step by ``slip``.
    Returns the shown pose's error against the truth at each poll (50 Hz)."""
    errors = []
    odo = [500.0, 200.0, 0.0]
    true = [500.0, 200.0, 0.0]
    last_seen = -1e9
    for i in range(int(seconds * 50)):
        t = i * 0.02
        step, turn = 2.0, 0.01
        true[2] += turn
        true[0] += step * math.cos(true[2])
        true[1] += step * math.sin(true[2])
        odo[2] += turn * (1 + slip)
        odo[0] += step * (1 + slip) * math.cos(odo[2])
        odo[1] += step * (1 + slip) * math.sin(odo[2])
        fusion.odometry("k1", *odo, at=t)
        if camera_every is not None and t - last_seen >= camera_every:
            fusion.camera_alive(t)
            fusion.seen("k1", *true, captured_at=t)
            last_seen = t
        shown = fusion.pose("k1", t)
        assert shown is not None
        errors.append(math.hypot(shown.x - true[0], shown.y - true[1]))
    return errors


def test_sightings_hold_a_slipping_robot_to_its_true_pose() -> None:
    alone = drive(PoseFusion(1000, 1000), 60, camera_every=None, slip=0.03)
    fused = drive(PoseFusion(1000, 1000), 60, camera_every=0.1, slip=0.03)
    assert max(alone[-500:]) > 30.0  # odometry alone drifts far
    assert max(fused) < 3.0  # a sighting each 0.1 s keeps it within millimetres


def test_a_robot_the_live_camera_lost_is_not_seen_where_it_was_last_trusted() -> None:
    fusion = PoseFusion(1000, 1000)
    fusion.odometry("k1", 300, 300, 0, at=0.0)
    fusion.camera_alive(0.0)
    fusion.seen("k1", 310, 305, 0.1, captured_at=0.0)
    fusion.odometry("k1", 300, 300, 0, at=0.1)
    assert fusion.pose("k1", 0.1).source == "tracked"  # type: ignore[union-attr]
    for t in (0.5, 1.0, 1.5):  # the camera sees the arena, but not k1 (a hand over it)
        fusion.camera_alive(t)
        fusion.odometry("k1", 300 + 1000 * t, 300, 0, at=t)  # odometry runs off
    shown = fusion.pose("k1", 1.5)
    assert shown is not None and shown.source == "not seen"
    assert (round(shown.x), round(shown.y)) == (310, 305)


def test_without_a_camera_odometry_is_shown_inside_the_arena() -> None:
    fusion = PoseFusion(1000, 1000)
    fusion.odometry("k1", 1400.0, -80.0, 0.0, at=0.0)
    shown = fusion.pose("k1", 0.0)
    assert shown is not None and shown.source == "odometry"
    assert (shown.x, shown.y) == (972.5, 27.5)


def test_a_camera_that_went_silent_leaves_the_robot_on_odometry() -> None:
    fusion = PoseFusion(1000, 1000)
    fusion.odometry("k1", 100, 100, 0, at=0.0)
    fusion.seen("k1", 200, 100, 0, captured_at=0.0)
    fusion.odometry("k1", 150, 100, 0, at=5.0)  # 50 mm on since the sighting
    shown = fusion.pose("k1", 5.0)
    assert shown is not None and shown.source == "odometry"
    assert round(shown.x) == 250  # the last correction carries on


def test_a_camera_on_a_host_whose_clock_is_off_still_corrects_the_right_pose() -> None:
    # The camera's host is 5 s behind; frames arrive 20 to 80 ms after their capture.
    clock, fusion = CameraClock(), PoseFusion(1000, 1000)
    true_x = lambda t: 100.0 + 50.0 * t  # noqa: E731 (50 mm/s along x; odometry 10 % long)
    for i in range(100):
        t = i * 0.1
        fusion.odometry("k1", 100.0 + 55.0 * t, 500.0, 0.0, at=t)
        if i >= 1:
            captured = t - 0.1  # the frame of 0.1 s ago, just arrived
            delay = 0.02 + 0.06 * ((i * 7) % 10) / 10
            stamped = captured - 5.0
            local = clock.local(stamped, captured + delay)
            assert abs(local - captured) <= 0.08
            fusion.camera_alive(captured + delay)
            fusion.seen("k1", true_x(captured), 500.0, 0.0, captured_at=local)
    shown = fusion.pose("k1", 9.9)
    assert shown is not None and shown.source == "tracked"
    # Paired with the odometry of the right moment: within the millimetres of 20 ms.
    assert abs(shown.x - true_x(9.9)) < 5.0
    # Taken at its word, the stamp is 5 s old on arrival: a robot in full view "not seen".
    naive = PoseFusion(1000, 1000)
    for i in range(100):
        naive.odometry("k1", 100.0 + 55.0 * i * 0.1, 500.0, 0.0, at=i * 0.1)
    naive.camera_alive(9.9)
    naive.seen("k1", true_x(9.8), 500.0, 0.0, captured_at=9.8 - 5.0)
    off = naive.pose("k1", 9.9)
    assert off is not None and off.source == "not seen"


def test_two_cameras_over_the_seam_give_one_pose_and_hand_over_without_a_jump() -> None:
    """A robot driving from the left camera's half to the right's: in the overlap both
    see it, 1 mm apart (each camera's own small error); its pose is their mean, not the
    two in turns, and when the left loses it the right holds it: tracked throughout."""
    fusion = PoseFusion(2000, 1000)
    shown_x: list[float] = []
    for i in range(200):  # 20 ms polls, 10 Hz cameras each, out of step
        t = i * 0.02
        x = 800.0 + 2.0 * i  # 100 mm/s from 800 to 1200
        fusion.odometry("k1", x, 500.0, 0.0, at=t)
        if i % 5 == 0 and x < 1100:  # the left camera sees up to 1100
            fusion.camera_alive(t)
            fusion.seen("k1", x - 0.5, 500.0, 0.0, captured_at=t, camera="left")
        if i % 5 == 2 and x > 900:  # the right from 900
            fusion.camera_alive(t)
            fusion.seen("k1", x + 0.5, 500.0, 0.0, captured_at=t, camera="right")
        shown = fusion.pose("k1", t)
        assert shown is not None and shown.source == "tracked"
        shown_x.append(shown.x - x)
    overlap = shown_x[70:130]  # x 940 to 1060: both see it
    assert max(abs(e) for e in overlap) < 0.01  # one pose: the mean, not +-0.5 in turns
    steps = [abs(b - a) for a, b in itertools.pairwise(shown_x)]
    assert max(steps) <= 0.5 + 1e-9  # the hand-overs: half the disagreement at most


def test_a_camera_gone_leaves_the_robots_it_alone_saw_on_odometry_and_others_tracked() -> None:
    fusion = PoseFusion(2000, 1000)
    fusion.odometry("k1", 300, 500, 0, at=0.0)  # under the left camera only
    fusion.odometry("k2", 1700, 500, 0, at=0.0)  # under the right camera only
    fusion.odometry("k3", 1000, 500, 0, at=0.0)  # on the seam: both
    fusion.camera_alive(0.0)
    fusion.seen("k1", 300, 500, 0, captured_at=0.0, camera="left")
    fusion.seen("k3", 1000, 500, 0, captured_at=0.0, camera="left")
    fusion.seen("k2", 1700, 500, 0, captured_at=0.0, camera="right")
    fusion.seen("k3", 1000, 500, 0, captured_at=0.0, camera="right")
    fusion.camera_left("left")
    for t in (0.1, 0.2, 1.5):  # the right camera carries on, seeing k2 and k3
        fusion.odometry("k1", 300 + 10 * t, 500, 0, at=t)
        fusion.odometry("k2", 1700, 500, 0, at=t)
        fusion.odometry("k3", 1000, 500, 0, at=t)
        fusion.camera_alive(t)
        fusion.seen("k2", 1700, 500, 0, captured_at=t, camera="right")
        fusion.seen("k3", 1000, 500, 0, captured_at=t, camera="right")
    k1, k2, k3 = (fusion.pose(a, 1.5) for a in ("k1", "k2", "k3"))
    assert k1 is not None and k1.source == "odometry"  # its camera is offline: said so
    assert round(k1.x) == 315  # the last correction carries its odometry on
    assert k2 is not None and k2.source == "tracked"
    assert k3 is not None and k3.source == "tracked"
    # The left camera back, still not seeing k1 (covered): not seen, as with one camera.
    fusion.camera_back("left")
    shown = fusion.pose("k1", 1.6)
    assert shown is not None and shown.source == "not seen"


def test_a_camera_gone_does_not_give_its_robot_back_to_one_that_saw_it_long_ago() -> None:
    fusion = PoseFusion(2000, 1000)
    fusion.odometry("k1", 1200, 500, 0, at=0.0)
    fusion.camera_alive(0.0)
    fusion.seen("k1", 1205, 500, 0, captured_at=0.0, camera="left")  # leaving its view
    for t in (1.0, 2.0):  # only the right camera sees it now; odometry slips 5 mm
        fusion.odometry("k1", 1200 + 100 * t, 500, 0, at=t)
        fusion.camera_alive(t)
        fusion.seen("k1", 1200 + 100 * t + 5 * t, 500, 0, captured_at=t, camera="right")
    fusion.camera_left("right")
    shown = fusion.pose("k1", 2.1)
    assert shown is not None and shown.source == "odometry"  # not "not seen" by the left
    assert round(shown.x) == 1410  # the right camera's correction, not the left's old one


def test_a_frames_processing_time_is_not_taken_for_the_clocks_difference() -> None:
    # The camera's host is 5 s behind; a frame takes 60 to 90 ms to be read and searched
    # before it is sent, then 1 to 3 ms on the network. Timed by its sending, each capture
    # lands within the network's delay of when it was; timed by its capture (an older
    # camera), every one lands at least the least processing time (60 ms) late.
    by_sent, by_capture = CameraClock(), CameraClock()
    for i in range(50):
        captured = 10.0 + i * 0.1
        sent = captured + 0.06 + 0.03 * ((i * 7) % 10) / 10
        arrived = sent + 0.001 + 0.002 * ((i * 3) % 10) / 10
        local = by_sent.local(captured - 5.0, arrived, sent_at=sent - 5.0)
        assert abs(local - captured) <= 0.0011, (i, local - captured)
        assert by_capture.local(captured - 5.0, arrived) - captured >= 0.06


def test_a_send_time_that_is_not_a_time_is_refused_on_the_wire() -> None:
    poses = TrackedPoses(world="w", camera="c", seq=1, captured_at=10.0, sent_at=1733390000.25)
    assert decode(encode(poses), TrackedPoses).sent_at == 1733390000.25
    for bad in (math.nan, -1.0, 0.0):
        with pytest.raises(MessageError, match="sent_at"):
            decode(encode(msgspec.structs.replace(poses, sent_at=bad)), TrackedPoses)


def test_late_odometry_and_late_frames_never_step_a_robot_driving_forward_back() -> None:
    # A loaded bridge: the robot drives at 160 mm/s along x, its odometry 3 % long; the
    # serial round reads the counters every 50 ms but stalls for 0.4 s twice, and its
    # readings then arrive together; each frame arrives 80 ms after its capture, and one
    # camera's frames come two at a time. Each reading and sighting is given its own time.
    # The pose published every 50 ms never goes back by more than the 3 % overshoot of
    # odometry between two frames (before: a frame newer than the newest reading was
    # paired with that reading, and its correction held the robot's whole drive since).
    fusion = PoseFusion(4000, 1000)
    true_x = lambda t: 100.0 + 160.0 * t  # noqa: E731
    odo_x = lambda t: 100.0 + 160.0 * 1.03 * t  # noqa: E731
    readings = [round(k * 0.05, 3) for k in range(200)]
    stalls = [(2.0, 2.4), (5.0, 5.4)]  # readings taken then arrive at the stall's end
    arrive = {
        t: next((end for start, end in stalls if start <= t < end), t + 0.01) for t in readings
    }
    frames = [round(0.03 + k * 0.1, 3) for k in range(95)]
    events = [(arrive[t], "odometry", t) for t in readings]
    events += [(c + 0.08 + (0.1 if k % 4 == 0 else 0.0), "frame", c) for k, c in enumerate(frames)]
    events += [(round(k * 0.05, 3) + 0.001, "publish", 0.0) for k in range(190)]
    shown: list[tuple[float, float, float]] = []  # (now, x shown, the newest frame's x)
    newest = 0.0
    for now, kind, t in sorted(events):
        if kind == "odometry":
            fusion.odometry("k1", odo_x(t), 500.0, 0.0, at=t)
        elif kind == "frame":
            fusion.camera_alive(now)
            fusion.seen("k1", true_x(t), 500.0, 0.0, captured_at=t, camera="left")
            newest = max(newest, t)
        elif (pose := fusion.pose("k1", now)) is not None:
            shown.append((now, pose.x, true_x(newest)))
    furthest, back = -math.inf, 0.0
    for _, x, _ in shown:
        furthest = max(furthest, x)
        back = max(back, furthest - x)
    assert back < 1.5, back
    # ... and through the stalls it is where the camera saw it last (or a reading newer
    # than that frame, 20 ms on), not left behind where the stalled odometry stopped.
    during = [x - seen for now, x, seen in shown if 2.2 <= now <= 2.4]
    assert during and all(-0.5 < e < 4.0 for e in during), during


def test_a_late_sighting_is_told_apart_from_a_camera_that_has_gone() -> None:
    """The bridge says why a robot is on odometry: its camera's frames are late (how late),
    or the camera's process has gone."""
    fusion = PoseFusion(1000, 1000)
    fusion.odometry("k1", 300, 300, 0, at=0.0)
    fusion.camera_alive(0.0)
    fusion.seen("k1", 310, 305, 0.1, captured_at=0.0, camera="left")
    fusion.odometry("k1", 350, 300, 0, at=0.7)
    fusion.camera_alive(0.7)  # the camera speaks, but its last sighting of k1 is 0.7 s old
    assert fusion.pose("k1", 0.7).source == "odometry"  # type: ignore[union-attr]
    assert fusion.sighting_age("k1", 0.7) == pytest.approx(0.7)
    fusion.camera_left("left")
    assert fusion.sighting_age("k1", 0.7) is None
    assert fusion.sighting_age("k9", 0.7) is None  # never seen
