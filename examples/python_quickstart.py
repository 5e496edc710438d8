#!/usr/bin/env python3
"""omnicml from Python in one page: simulate a short log, run the CML engine over it,
print the localization error against ground truth, save and reload the engine.

    cmake --build build --target omnicml_python
    PYTHONPATH=build/python /usr/bin/python3 examples/python_quickstart.py [--days 2] [--frames 300]

Day 1 builds the map (error close to dead reckoning until the loop closes); on day 2 the
odometry restarts and drifts, while the engine localizes on the learned map.
"""

import argparse
import os
import tempfile

import numpy as np

import omnicml


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="home_store", help=", ".join(omnicml.world_names()))
    parser.add_argument("--days", type=int, default=2, help="simulated days (sessions)")
    parser.add_argument("--frames", type=int, default=300, help="frames per simulated day")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()

    # Simulated days of panoramas with odometry and ground truth, written as a log on disk
    # and read back (the same as `omnicml simulate --panorama`).
    sim = omnicml.Simulator(args.world, days=args.days, frames_per_day=args.frames,
                            seed=args.seed, panorama=True)
    log_dir = os.path.join(tempfile.mkdtemp(prefix="omnicml-"), "log")
    writer = omnicml.LogWriter(log_dir)
    session = -1
    for frame in sim:
        if frame.session_index != session:
            session = frame.session_index
            writer.begin_session(sim.session(session))
        writer.write(frame)
    writer.finish()
    reader = omnicml.LogReader(log_dir)
    print("log:", log_dir, omnicml.validate_log(log_dir)["total_frames"], "frames")

    # The engine, options as a dict (the keys of an engine YAML file).
    engine = omnicml.CmlEngine({"threads": 2, "model": {"forgetting": {"mode": "active"}}})
    errors = [[] for _ in range(reader.num_sessions)]
    odom_errors = [[] for _ in range(reader.num_sessions)]
    for frame in reader:
        if engine.session < frame.session_index:  # a new day
            engine.begin_session(reader.session(frame.session_index))
        result = engine.process_frame(frame.image, frame.odom_pose, frame.stamp_s)
        if result.estimate is not None:
            errors[frame.session_index].append(np.hypot(*(result.pose[:2] - frame.truth[:2])))
            odom_errors[frame.session_index].append(
                np.hypot(*(frame.odom_pose[:2] - frame.truth[:2])))
    engine.finish()

    for day, (err, odom) in enumerate(zip(errors, odom_errors)):
        print("day %d position error: mean %.3f m, max %.3f m (odometry alone: mean %.3f m)"
              % (day + 1, np.mean(err), np.max(err), np.mean(odom)))
    m = engine.map
    print("map: %d views, %d components, weights %.2f..%.2f"
          % (m.num_views, m.num_components, m.weights.min(), m.weights.max()))

    # Save and reload: bit-identical state.
    path = os.path.join(os.path.dirname(log_dir), "engine.omap")
    engine.save(path)
    assert omnicml.CmlEngine.load(path).to_bytes() == engine.to_bytes()
    print("engine saved:", path)


if __name__ == "__main__":
    main()
