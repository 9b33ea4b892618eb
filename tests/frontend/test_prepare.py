"""Work done ahead of tracking (:class:`vslam.frontend.prepare.FramePreparer`): for a stereo pair the
detection and the keypoints' depth, identical to what the tracker's own observer finds."""
from __future__ import annotations

import pickle

import numpy as np

from vslam.datasets.synthetic.sequence import SyntheticConfig, SyntheticSequence
from vslam.features import FeatureConfig
from vslam.frontend import observe
from vslam.frontend.config import FrontendConfig
from vslam.frontend.observe import Observer
from vslam.frontend.prepare import Detection, FramePreparer
from vslam.map.map import Map


def _stereo_frame():
    seq = SyntheticSequence(SyntheticConfig(n_frames=2, laps=0.05, baseline=0.1, pixel_noise=0.0, seed=1))
    return next(iter(seq)), seq.camera


def test_stereo_detection_prepared_ahead_is_the_observers_own(monkeypatch):
    frame, cam = _stereo_frame()
    fcfg, feat = FrontendConfig(), FeatureConfig()
    preparer = pickle.loads(pickle.dumps(FramePreparer(feat, "match", cam, "stereo", fcfg.depth)))  # as sent to a process
    gray, det = preparer(frame)
    assert isinstance(det, Detection) and len(det.stereo[0]) == len(det.features) > 500
    own = Observer(fcfg, feat, cam, "stereo", Map()).detect(frame, gray)

    def no_stereo(*args, **kwargs):
        raise AssertionError("the stereo depth was prepared ahead")

    monkeypatch.setattr(observe, "stereo_pair_depth", no_stereo)
    ahead = Observer(fcfg, feat, cam, "stereo", Map())
    ahead.prepared_feats = det
    obs = ahead.detect(frame, gray)
    for name in ("uv", "uv_undist", "descriptors", "octave", "depth", "u_right", "point_ids"):
        np.testing.assert_array_equal(getattr(obs, name), getattr(own, name), err_msg=name)
    assert np.isfinite(obs.depth).sum() > 300  # real depths, not all NaN
    assert ahead.prepared_feats is None  # used once


def test_without_a_right_image_or_camera_only_features_are_prepared():
    frame, cam = _stereo_frame()
    fcfg, feat = FrontendConfig(), FeatureConfig()
    _, feats = FramePreparer(feat, "match")(frame)  # the localizer's preparer: features only
    assert not isinstance(feats, Detection) and len(feats) > 500
    frame.image_right = None
    _, feats = FramePreparer(feat, "match", cam, "stereo", fcfg.depth)(frame)  # the tracker reports it
    assert not isinstance(feats, Detection)
    assert FramePreparer(feat, "track", cam, "stereo", fcfg.depth)(frame)[1] is None  # KLT detects with a mask
