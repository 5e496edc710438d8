"""run and compare from Python: their tables as numpy arrays, and the run directory."""

import os
import tempfile
import unittest

import numpy as np

import _support  # noqa: F401
import omnicml


class ExperimentsTest(unittest.TestCase):
    def test_run_over_two_simulated_days(self):
        # Per-frame arrays of both days, per-day statistics, the engine after finish(); the
        # run directory's frames.csv evaluates to the same statistics.
        with tempfile.TemporaryDirectory() as tmp:
            out = os.path.join(tmp, "run")
            r = omnicml.run(world="home_store", days=2, frames_per_day=80, seed=1,
                            options={"threads": 1}, out_dir=out,
                            map_out=os.path.join(tmp, "map.omap"))
            self.assertEqual(r.num_frames, 160)
            self.assertEqual(r.num_sessions, 2)
            self.assertEqual(r.frames["estimate"].shape, (160, 3))
            np.testing.assert_array_equal(r.frames["session"], [0] * 80 + [1] * 80)
            err = r.frames["position_error_m"]
            self.assertTrue(np.all(np.isfinite(err)))
            self.assertAlmostEqual(r.mean_error_m, float(err.mean()), places=9)
            self.assertLess(r.mean_error_m, 1.0)
            # The estimate's covariance and the NEES e^T C^-1 e (every frame localized).
            e_xy = r.frames["estimate"][:, :2] - r.frames["truth"][:, :2]
            a, b, d = r.frames["cov_xx_m2"], r.frames["cov_xy_m2"], r.frames["cov_yy_m2"]
            det = a * d - b * b
            self.assertTrue(np.all(det > 0))
            nees = (d * e_xy[:, 0] ** 2 - 2 * b * e_xy[:, 0] * e_xy[:, 1] + a * e_xy[:, 1] ** 2) / det
            np.testing.assert_allclose(r.frames["nees_xy"], nees, rtol=1e-9, atol=1e-12)
            self.assertEqual(len(r.days), 2)
            self.assertEqual(r.days[1]["frames"], 80)
            self.assertEqual(r.days[1]["views_at_end"], r.frames["views"][-1])
            # finish() applied the updates still queued at the last frame; the engine
            # returned is the resumable state before it.
            self.assertGreaterEqual(r.views, r.days[1]["views_at_end"])
            self.assertEqual(r.engine.num_views, r.frames["views"][-1])
            self.assertEqual(r.engine.counters["frames"], 160)
            self.assertEqual(r.run_dir, out)
            for name in ("frames.csv", "days.csv", "config.yaml", "report.html"):
                self.assertTrue(os.path.isfile(os.path.join(out, name)), name)
            e = omnicml.evaluate(out)
            self.assertAlmostEqual(e["overall"]["position_m"]["mean"], r.mean_error_m, places=6)
            # Resuming the saved map on day 3 with the map of days 1-2.
            r3 = omnicml.run(world="home_store", days=1, first_day=2, frames_per_day=40, seed=1,
                             map_in=os.path.join(tmp, "map.omap"), forgetting="static")
            self.assertEqual(r3.num_frames, 40)
            self.assertEqual(r3.run_dir, "")
            # A frozen map (the saved one, before finish): no view added or removed on day 3.
            self.assertEqual(set(r3.frames["views"].tolist()), {int(r.frames["views"][-1])})
            with self.assertRaises(omnicml.Error):
                omnicml.run(world="home_store", map_in=os.path.join(tmp, "map.omap"),
                            options={"threads": 1})

    def test_compare_table(self):
        # Three modes on the same frames; static is frozen after day 1 (its map does not
        # change on day 2), views_at reads the per-frame view counts.
        c = omnicml.compare(world="home_store", days=2, frames_per_day=60, seed=1,
                            options={"threads": 1}, steps=[30, 90, 500], jobs=1)
        self.assertEqual(list(c.table["forgetting"]), ["passive", "active", "static"])
        self.assertEqual(c.table["views_at"].shape, (3, 3))
        self.assertTrue(np.all(c.table["views_at"][:, 2] == -1))  # beyond the run
        for i, mode in enumerate(c.table["forgetting"]):
            run = c.runs[mode]
            self.assertEqual(run.num_frames, 120)
            self.assertEqual(c.table["views_at"][i, 0], run.frames["views"][29])
            self.assertEqual(c.table["views_end"][i], run.views)
            self.assertIsNone(run.engine)
            self.assertAlmostEqual(c.table["mean_err_m"][i], run.mean_error_m)
        static = c.runs["static"].frames["views"]
        self.assertEqual(len(set(static[60:].tolist())), 1)
        # Modes share the frames: odometry error is the same in every row.
        self.assertEqual(len(set(c.table["odom_err_m"].tolist())), 1)
        self.assertIn("views@30", c.table_text)


if __name__ == "__main__":
    unittest.main()
