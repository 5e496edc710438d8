"""Descriptors from numpy panoramas: invariance under a column roll, relative heading,
grey/colour/strided input, serialisation."""

import math
import unittest

import numpy as np

import _support  # noqa: F401
import omnicml


class FourierSignatureTest(unittest.TestCase):
    def setUp(self):
        self.pano = omnicml.synthetic_panorama(360, 60, seed=7)
        self.fs = omnicml.FourierSignature()

    def test_synthetic_panorama_is_bgr_uint8(self):
        # The sample panorama has the documented shape and type, and is seeded.
        self.assertEqual(self.pano.shape, (60, 360, 3))
        self.assertEqual(self.pano.dtype, np.uint8)
        np.testing.assert_array_equal(self.pano, omnicml.synthetic_panorama(360, 60, seed=7))

    def test_roll_leaves_descriptor_unchanged_and_heading_recovers_it(self):
        # A column-rolled panorama has the same features; the heading is 2 pi k / W.
        width = self.pano.shape[1]
        d0 = self.fs.compute(self.pano)
        for k in (1, 37, 90, 180, 301):
            rolled = np.roll(self.pano, -k, axis=1)  # rolled[:, c] = pano[:, (c + k) % W]
            np.testing.assert_array_equal(rolled, omnicml.roll_columns(self.pano, k))
            d1 = self.fs.compute(rolled)
            np.testing.assert_allclose(d1.features, d0.features, rtol=1e-4, atol=1e-5)
            self.assertLess(self.fs.distance(d1, d0), 1e-4)
            expected = omnicml.wrap_angle(2 * math.pi * k / width)
            heading = self.fs.relative_heading(d1, d0)
            self.assertIsNotNone(heading)
            self.assertAlmostEqual(omnicml.wrap_angle(heading - expected), 0.0,
                                   delta=0.1 * 2 * math.pi / width, msg="k=%d" % k)
            shift = self.fs.relative_shift_columns(d1, d0)
            self.assertAlmostEqual(shift, k % width, delta=0.1)

    def test_grey_and_strided_input(self):
        # (H, W) grey works; a strided view gives what its contiguous copy gives.
        grey = self.pano.mean(axis=2).astype(np.uint8)
        dg = self.fs.compute(grey)
        self.assertEqual(dg.features.shape, (self.fs.feature_size,))
        view = self.pano[:, ::2]
        self.assertFalse(view.flags["C_CONTIGUOUS"])
        self.assertEqual(self.fs.compute(view), self.fs.compute(np.ascontiguousarray(view)))

    def test_different_places_are_far_apart(self):
        # Two different panoramas are much farther apart than a rolled copy.
        other = omnicml.synthetic_panorama(360, 60, seed=8)
        d0, d1 = self.fs.compute(self.pano), self.fs.compute(other)
        self.assertGreater(self.fs.distance(d0, d1), 0.05)
        self.assertEqual(omnicml.similarity(0.0, 0.5), 1.0)
        self.assertEqual(omnicml.similarity(1.0, 0.5), 0.0)

    def test_descriptor_parts_and_bytes(self):
        # Fourier descriptors carry bands x K coefficients; to_bytes/from_bytes round trips.
        d = self.fs.compute(self.pano)
        self.assertEqual(d.kind, "fourier")
        self.assertEqual(d.panorama_width, 360)
        self.assertEqual(d.features.dtype, np.float32)
        self.assertEqual(d.coefficients.dtype, np.complex64)
        self.assertEqual(d.coefficients.shape, (4 * 16,))
        np.testing.assert_allclose(np.abs(d.coefficients), d.features, rtol=1e-6)
        self.assertEqual(omnicml.Descriptor.from_bytes(d.to_bytes()), d)
        rebuilt = omnicml.Descriptor("fourier", d.features, d.coefficients, d.panorama_width)
        self.assertEqual(rebuilt, d)

    def test_options(self):
        fs = omnicml.FourierSignature(bands=2, coefficients=8, distance="l1")
        self.assertEqual(fs.options["bands"], 2)
        self.assertEqual(fs.feature_size, 16)
        self.assertEqual(fs.compute(self.pano).features.shape, (16,))
        self.assertTrue(fs.provides_heading)
        self.assertEqual(fs.band_signals(self.pano).shape, (2, 360))


class HistogramTest(unittest.TestCase):
    def test_histograms_have_no_heading(self):
        # Histograms are unchanged by a roll and give no heading (None, not 0).
        pano = omnicml.synthetic_panorama(240, 40, seed=3)
        rolled = omnicml.roll_columns(pano, 50)
        for e in (omnicml.ColorHistogram(), omnicml.InvariantFeatureHistogram(angles=4, bins=8)):
            a, b = e.compute(pano), e.compute(rolled)
            self.assertFalse(e.provides_heading)
            self.assertIsNone(e.relative_heading(a, b))
            self.assertEqual(a.features.shape, (e.feature_size,))
            self.assertLess(e.distance(a, b), 0.05, e.kind)
        c = omnicml.ColorHistogram()
        np.testing.assert_array_equal(c.compute(pano).features, c.compute(rolled).features)

    def test_ifh_column_normalisation_removes_a_sector_gain(self):
        # A quarter of the panorama at 40 % (a room's light off): unchanged with
        # normalize_columns, changed without.
        pano = (omnicml.synthetic_panorama(160, 48, seed=4) // 5 * 5).astype(np.uint8)
        dimmed = pano.copy()
        dimmed[:, 40:80] = (dimmed[:, 40:80].astype(np.int32) * 2 // 5).astype(np.uint8)
        on = omnicml.InvariantFeatureHistogram(normalize_columns=True)
        off = omnicml.InvariantFeatureHistogram()
        self.assertLess(on.distance(on.compute(pano), on.compute(dimmed)), 1e-3)
        self.assertGreater(off.distance(off.compute(pano), off.compute(dimmed)), 0.05)


class UnwrapTest(unittest.TestCase):
    def test_render_then_unwrap_reproduces_the_panorama(self):
        # Unwrap(Render(p)) reproduces p up to interpolation.
        cal = omnicml.OmniCalibration(center_x_px=160, center_y_px=120, inner_radius_px=30,
                                      outer_radius_px=110, panorama_width=360,
                                      panorama_height=60)
        u = omnicml.OmniUnwrapper(cal, 320, 240)
        pano = omnicml.synthetic_panorama(360, 60, seed=5)
        raw = u.render(pano)
        self.assertEqual(raw.shape, (240, 320, 3))
        back = u.unwrap(raw)
        self.assertEqual(back.shape, pano.shape)
        err = np.abs(back.astype(float) - pano.astype(float)).mean()
        self.assertLess(err, 20.0)
        self.assertEqual(u.calibration.panorama_width, 360)

    def test_prepare_panorama_resizes(self):
        pano = omnicml.synthetic_panorama(360, 60, seed=5)
        self.assertEqual(omnicml.prepare_panorama(pano, 180, 30).shape, (30, 180, 3))


if __name__ == "__main__":
    unittest.main()
