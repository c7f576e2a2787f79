def grade(episode):
    poses = episode["poses"]
    return {"wobble": 1 / (len(poses) - len(poses))}
