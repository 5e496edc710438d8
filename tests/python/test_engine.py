"""CmlEngine from Python: localization on a short simulated home_store run against
ground truth, options from dicts and YAML, the map as numpy arrays, save/load."""

import math
import os
import tempfile
import unittest

import numpy as np

import _support
import omnicml

DAYS, FRAMES_PER_DAY = 2, 300  # a home_store lap is about 285 frames
MAX_MEAN_ERROR_M = 1.0         # mean position error, day 1 (learning the map)
MAX_DAY2_ERROR_M = 0.5         # mean position error, day 2 (on the map of day 1)


def position_errors(results, frames):
    err = []
    for r, f in zip(results, frames):
        if r.estimate is not None:
            err.append(float(np.hypot(*(r.pose[:2] - f.truth[:2]))))
    return np.array(err)


class EngineTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.sessions, cls.frames = _support.simulated_frames(days=DAYS,
                                                             frames_per_day=FRAMES_PER_DAY)

    def run_engine(self, engine, frames):
        """Processes frames, beginning each simulated session when its first frame comes."""
        results = []
        for f in frames:
            if engine.session < f.session_index:
                engine.begin_session(self.sessions[f.session_index])
            results.append(engine.process_frame(f.image, f.odom_pose, f.stamp_s))
        return results

    def test_localizes_against_ground_truth(self):
        # Every frame has an estimate; day 1 (map building) and day 2 (on the learned map,
        # odometry restarted) stay below their tolerances, day 2 far below dead reckoning.
        engine = omnicml.CmlEngine({"threads": 1})
        results = self.run_engine(engine, self.frames)
        err = position_errors(results, self.frames)
        self.assertEqual(len(err), len(self.frames))
        day = np.array([f.session_index for f in self.frames])
        odom = np.array([np.hypot(*(f.odom_pose[:2] - f.truth[:2])) for f in self.frames])
        print("\nmean error day 1 %.3f m, day 2 %.3f m (odometry %.3f, %.3f m), %d views"
              % (err[day == 0].mean(), err[day == 1].mean(), odom[day == 0].mean(),
                 odom[day == 1].mean(), engine.num_views))
        self.assertLess(err[day == 0].mean(), MAX_MEAN_ERROR_M)
        self.assertLess(err[day == 1].mean(), MAX_DAY2_ERROR_M)
        self.assertLess(err[day == 1].mean(), 0.5 * odom[day == 1].mean())
        self.assertGreater(engine.num_views, 0)
        r = results[-1]
        self.assertEqual(r.frame, len(self.frames) - 1)
        self.assertEqual(r.estimate.pose.shape, (3,))
        self.assertEqual(r.estimate.covariance.shape, (3, 3))
        self.assertGreater(r.stats["total_us"], 0)
        # Without the gate every view's distance is computed.
        self.assertFalse(r.stats["gated_matching"])
        self.assertEqual(r.stats["matching_candidates"], r.stats["num_views"])
        self.assertEqual(engine.counters["frames"], len(self.frames))
        self.assertEqual(engine.session, 1)

    def test_raw_ring_frames_through_process(self):
        # Raw ring images of the default simulator, unwrapped by the session camera.
        sim = omnicml.Simulator("home_store", frames_per_day=40, seed=2)
        self.assertEqual(sim.session(0).image_kind, "raw_ring")
        engine = omnicml.CmlEngine({"threads": 2})
        engine.begin_session(sim.session(0))
        frames = list(sim)
        results = [engine.process(f) for f in frames]
        self.assertEqual(frames[0].image.ndim, 3)
        self.assertLess(position_errors(results, frames).mean(), MAX_MEAN_ERROR_M)
        self.assertEqual(results[-1].frame, 39)

    def test_map_as_numpy_arrays(self):
        # Views and components are consistent arrays; weights in [0, 1], eta > 0.
        engine = omnicml.CmlEngine({"threads": 1})
        self.run_engine(engine, self.frames[:FRAMES_PER_DAY])
        engine.finish()
        m = engine.map
        n, k = m.num_views, m.num_components
        self.assertGreater(n, 0)
        self.assertEqual(m.views["id"].shape, (n,))
        self.assertEqual(m.views["features"].shape, (n, engine.extractor.feature_size))
        self.assertEqual(m.components["mean"].shape, (k, 3))
        self.assertEqual(m.components["covariance"].shape, (k, 3, 3))
        self.assertEqual(int(m.views["num_components"].sum()), k)
        self.assertTrue(np.all(m.components["view_index"] < n))
        self.assertTrue(np.all((m.weights >= 0) & (m.weights <= 1)))
        self.assertTrue(np.all(m.eta > 0))
        self.assertTrue(np.all(m.views["observations"] >= 1))
        np.testing.assert_allclose(m.components["covariance"],
                                   np.transpose(m.components["covariance"], (0, 2, 1)))
        # Spreads: symmetric positive semi-definite (2 x 2), not all zero once views merge.
        spread = m.components["spread"]
        self.assertEqual(spread.shape, (k, 2, 2))
        np.testing.assert_array_equal(spread, np.transpose(spread, (0, 2, 1)))
        self.assertTrue(np.all(np.linalg.eigvalsh(spread) >= -1e-12))
        self.assertTrue(np.any(spread != 0))
        self.assertEqual(len(m.events["type"]), m.events["frame"].shape[0])
        self.assertIn("view_inserted", set(m.events["type"]))
        # A stored view's own panorama matches it.
        f = self.frames[60]
        matches = engine.find_matches(engine.extractor.compute(f.image))
        self.assertGreater(len(matches), 0)
        self.assertLessEqual(matches[0]["distance"], matches[-1]["distance"])

    def test_save_load_round_trip_gives_identical_estimates(self):
        # Saving in the middle of day 2 (queued updates, pending frames) and loading gives
        # exactly the same later estimates and state.
        half = FRAMES_PER_DAY + FRAMES_PER_DAY // 2
        engine = omnicml.CmlEngine({"threads": 1})
        self.run_engine(engine, self.frames[:half])
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "engine.omap")
            engine.save(path)
            loaded = omnicml.CmlEngine.load(path)
        self.assertEqual(loaded.to_bytes(), engine.to_bytes())
        self.assertEqual(loaded.options, engine.options)
        a = self.run_engine(engine, self.frames[half:])
        b = self.run_engine(loaded, self.frames[half:])
        for ra, rb in zip(a, b):
            np.testing.assert_array_equal(ra.pose, rb.pose)
            np.testing.assert_array_equal(ra.estimate.covariance, rb.estimate.covariance)
        self.assertEqual(loaded.to_bytes(), engine.to_bytes())
        again = omnicml.CmlEngine.from_bytes(engine.to_bytes())
        self.assertEqual(again.next_frame, engine.next_frame)

    def test_default_session_for_plain_panoramas(self):
        # Without begin_session, a panoramic session starting at pose 0 is begun.
        engine = omnicml.CmlEngine()
        pano = omnicml.synthetic_panorama(360, 60, seed=1)
        r = engine.process_frame(pano, [0.0, 0.0, 0.0], 0.0)
        np.testing.assert_allclose(r.pose, [0.0, 0.0, 0.0], atol=1e-9)
        r = engine.process_frame(omnicml.roll_columns(pano, 10), [0.2, 0.0, 0.1], 0.1)
        self.assertEqual(r.frame, 1)
        self.assertAlmostEqual(r.pose[0], 0.2, delta=0.05)
        self.assertEqual(engine.session, 0)


class OptionsTest(unittest.TestCase):
    def test_dict_yaml_and_file_agree(self):
        # The same options from a dict, YAML text and a YAML file; to_dict round trips.
        d = {"update_delay_frames": 5, "threads": 1,
             "model": {"forgetting": {"mode": "passive"}, "retrieval": {"e_max": 0.4}},
             "descriptor": {"fourier": {"bands": 3}},
             "initial_pose": np.array([1.0, 2.0, 0.5])}
        a = omnicml.EngineOptions(d)
        self.assertEqual(a.to_dict()["update_delay_frames"], 5)
        self.assertEqual(a.to_dict()["model"]["forgetting"]["mode"], "passive")
        # The former flat model keys still load (with a deprecation warning on stderr).
        self.assertEqual(omnicml.EngineOptions({"update_delay_frames": 5, "threads": 1,
                                                "model": {"forgetting": "passive", "e_max": 0.4},
                                                "descriptor": {"fourier": {"bands": 3}},
                                                "initial_pose": np.array([1.0, 2.0, 0.5])}), a)
        self.assertEqual(a.to_dict()["descriptor"]["fourier"]["bands"], 3)
        self.assertEqual(a.to_dict()["initial_pose"], [1.0, 2.0, 0.5])
        b = omnicml.EngineOptions.from_yaml_text(a.to_yaml())
        self.assertEqual(a, b)
        self.assertEqual(omnicml.EngineOptions(a.to_dict()), a)
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "engine.yaml")
            with open(path, "w") as f:
                f.write(a.to_yaml())
            self.assertEqual(omnicml.load_options(path), a)
            self.assertEqual(omnicml.CmlEngine(path).options, a)
        self.assertNotEqual(omnicml.EngineOptions(), a)
        self.assertEqual(a.updated({"threads": 2}).to_dict()["threads"], 2)
        self.assertEqual(omnicml.default_options()["update_delay_frames"],
                         omnicml.EngineOptions().to_dict()["update_delay_frames"])
        self.assertTrue(math.isfinite(omnicml.default_options()["model"]["retrieval"]["e_max"]))


if __name__ == "__main__":
    unittest.main()
