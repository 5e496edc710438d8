"""Library errors become omnicml.Error (a RuntimeError) with the C++ message."""

import os
import tempfile
import unittest

import numpy as np

import _support  # noqa: F401
import omnicml


class ErrorTest(unittest.TestCase):
    def test_error_class(self):
        # omnicml.Error is a RuntimeError (like omnicml::Error, a std::runtime_error).
        self.assertTrue(issubclass(omnicml.Error, RuntimeError))
        self.assertTrue(issubclass(omnicml.InternalError, RuntimeError))

    def test_invalid_option_keeps_the_message(self):
        # The exact message of FourierOptions::Validate.
        with self.assertRaises(omnicml.Error) as cm:
            omnicml.FourierSignature(bands=0)
        self.assertEqual(str(cm.exception), "FourierOptions.bands must be in 1..64, got 0")
        with self.assertRaises(omnicml.Error) as cm:
            omnicml.FourierSignature(distance="l3")
        self.assertEqual(str(cm.exception), "unknown Fourier distance 'l3' (expected l1 or l2)")

    def test_unknown_option_key_is_named(self):
        # An unknown key in an options dict names its section path.
        with self.assertRaises(omnicml.Error) as cm:
            omnicml.CmlEngine({"tracker": {"gama": 1.0}})
        self.assertIn("unknown key 'tracker.gama'", str(cm.exception))
        with self.assertRaises(omnicml.Error):
            omnicml.CmlEngine({"threads": 0})

    def test_yaml_file_errors_name_file_and_line(self):
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "engine.yaml")
            with open(path, "w") as f:
                f.write("threads: 1\nupdate_delay_framez: 3\n")
            with self.assertRaises(omnicml.Error) as cm:
                omnicml.CmlEngine(path)
            self.assertIn(path + ":2", str(cm.exception))
            self.assertIn("update_delay_framez", str(cm.exception))

    def test_engine_file_errors_name_the_path(self):
        with tempfile.TemporaryDirectory() as tmp:
            missing = os.path.join(tmp, "missing.omap")
            with self.assertRaises(omnicml.Error) as cm:
                omnicml.CmlEngine.load(missing)
            self.assertTrue(str(cm.exception).startswith(missing + ": "), str(cm.exception))
            garbage = os.path.join(tmp, "garbage.omap")
            with open(garbage, "wb") as f:
                f.write(b"definitely not an engine file")
            with self.assertRaises(omnicml.Error) as cm:
                omnicml.CmlEngine.load(garbage)
            self.assertTrue(str(cm.exception).startswith(garbage + ": "), str(cm.exception))

    def test_bad_images(self):
        # Wrong dtype, shape or type: omnicml.Error naming the argument.
        fs = omnicml.FourierSignature()
        with self.assertRaises(omnicml.Error) as cm:
            fs.compute(np.zeros((60, 360), dtype=np.float64))
        self.assertIn("image: dtype float64", str(cm.exception))
        with self.assertRaises(omnicml.Error):
            fs.compute(np.zeros((60, 360, 4), dtype=np.uint8))
        with self.assertRaises(omnicml.Error):
            fs.compute([[1, 2], [3, 4]])
        with self.assertRaises(omnicml.Error):  # too small: the library's own check
            fs.compute(np.zeros((2, 8), dtype=np.uint8))

    def test_engine_rejects_bad_odometry(self):
        engine = omnicml.CmlEngine({"threads": 1})
        pano = omnicml.synthetic_panorama(360, 60, seed=1)
        with self.assertRaises(omnicml.Error) as cm:
            engine.process_frame(pano, [float("nan"), 0.0, 0.0], 0.0)
        self.assertIn("odometry is not finite", str(cm.exception))
        with self.assertRaises(omnicml.Error):
            engine.process_frame(pano, [0.0, 0.0], 0.0)

    def test_missing_log(self):
        with self.assertRaises(omnicml.Error):
            omnicml.LogReader("/nonexistent/omnicml/log")
        with self.assertRaises(omnicml.Error):
            omnicml.Simulator("no_such_world", frames_per_day=2)


if __name__ == "__main__":
    unittest.main()
