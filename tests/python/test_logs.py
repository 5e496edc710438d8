"""Logs from Python: a simulated log written with LogWriter reads back frame for frame
(images as numpy arrays, odometry, ground truth) with LogReader."""

import os
import tempfile
import unittest

import numpy as np

import _support  # noqa: F401
import omnicml


class LogTest(unittest.TestCase):
    def test_simulator_frames_have_ground_truth(self):
        sim = omnicml.Simulator("home_store", days=2, frames_per_day=5, seed=1, panorama=True)
        self.assertIn("home_store", omnicml.world_names())
        self.assertEqual(sim.num_sessions, 2)
        self.assertGreater(sim.route_length_m, 10)
        self.assertEqual(sim.route(1.0).shape[1], 2)
        frames = list(sim)
        self.assertEqual(len(frames), 10)
        self.assertEqual([f.session_index for f in frames], [0] * 5 + [1] * 5)
        for f in frames:
            self.assertEqual(f.image.dtype, np.uint8)
            self.assertEqual(f.truth.shape, (3,))
            self.assertEqual(f.odom_pose.shape, (3,))
        # Consecutive truth poses are step_m (0.2 m) apart.
        step = np.hypot(*(frames[1].truth[:2] - frames[0].truth[:2]))
        self.assertAlmostEqual(step, 0.2, delta=0.02)

    def test_write_then_read_back(self):
        sim = omnicml.Simulator("home_store", days=2, frames_per_day=4, seed=3, panorama=True)
        sessions = sim.sessions
        frames = list(sim)
        with tempfile.TemporaryDirectory() as tmp:
            log = os.path.join(tmp, "log")
            writer = omnicml.LogWriter(log)
            for s, info in enumerate(sessions):
                writer.begin_session(info)
                for f in frames:
                    if f.session_index == s:
                        writer.write(f)
            writer.finish()
            summary = omnicml.validate_log(log)
            self.assertEqual(summary["total_frames"], len(frames))
            self.assertEqual(len(summary["sessions"]), 2)
            reader = omnicml.LogReader(log)
            self.assertEqual(reader.num_sessions, 2)
            self.assertEqual(reader.session(0).image_kind, "panorama")
            back = list(reader)
        self.assertEqual(len(back), len(frames))
        for a, b in zip(frames, back):
            np.testing.assert_array_equal(a.image, b.image)  # PNG: lossless
            np.testing.assert_allclose(a.odom_pose, b.odom_pose, atol=1e-12)
            np.testing.assert_allclose(a.truth, b.truth, atol=1e-12)
            self.assertEqual(a.stamp_s, b.stamp_s)
            self.assertEqual(a.session_index, b.session_index)

    def test_frames_and_sessions_from_python(self):
        pano = omnicml.synthetic_panorama(120, 30, seed=2)
        f = omnicml.Frame(pano, [1.0, 2.0, 0.5], 3.0, truth=[1.1, 2.1, 0.4])
        np.testing.assert_array_equal(f.image, pano)
        f.truth = None
        self.assertIsNone(f.truth)
        s = omnicml.SessionInfo("day1", start_mode="global", start_pose=[1, 2, 3])
        self.assertEqual(s.start_mode, "global")
        np.testing.assert_array_equal(s.start_pose, [1, 2, 3])
        with self.assertRaises(omnicml.Error):
            omnicml.SessionInfo("x", start_mode="sideways")


if __name__ == "__main__":
    unittest.main()
