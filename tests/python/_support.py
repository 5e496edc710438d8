"""Shared set-up of the Python tests: imports omnicml from PYTHONPATH (build/python) and
gives small simulated inputs."""

import os
import sys

import numpy as np  # noqa: F401  (re-exported for the tests)

try:
    import omnicml  # noqa: F401
except ImportError as e:  # pragma: no cover - a set-up problem, not a test failure
    sys.stderr.write(
        "cannot import omnicml (%s); run with PYTHONPATH=<build>/python after building "
        "the omnicml_python target\n" % e)
    raise

SOURCE_DIR = os.environ.get(
    "OMNICML_SOURCE_DIR", os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..")))


def simulated_frames(world="home_store", days=1, frames_per_day=60, seed=1, panorama=True):
    """(sessions, frames) of a short simulated log, all frames in memory."""
    sim = omnicml.Simulator(world, days=days, frames_per_day=frames_per_day, seed=seed,
                            panorama=panorama)
    return sim.sessions, list(sim)
