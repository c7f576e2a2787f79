"""A teacher's grader: how much the robot turned (wobble, in radians) and its IR peak."""

import itertools


def grade(episode):
    headings = [p[3] for p in episode["poses"]]
    wobble = sum(abs(b - a) for a, b in itertools.pairwise(headings))
    peak = max((max(row[1:]) for row in episode["ir"]), default=0)
    return {"wobble": wobble, "ir_peak": peak, "samples": len(episode["poses"])}
