"""``vslam vocab train / info / convert`` on a real 9-frame TUM clip."""
from __future__ import annotations

import numpy as np
import pytest

from vslam.cli import main
from vslam.loop.vocabulary import Vocabulary


@pytest.mark.shared
def test_vocab_train_info_convert(shared_data, tmp_path, capsys):
    source = shared_data / "tum_rgbd_freiburg1_desk_9frames"
    out = tmp_path / "voc.npz"
    assert main(["vocab", "train", str(source), "--output", str(out), "--k", "4", "--levels", "3",
                 "--every", "2", "--max-frames", "4"]) == 0
    assert "4 images" in capsys.readouterr().out
    voc = Vocabulary.load(out)
    assert (voc.k, voc.levels) == (4, 3) and 40 <= voc.n_words <= 64
    txt = tmp_path / "voc.txt"
    assert main(["vocab", "convert", str(out), str(txt)]) == 0
    assert txt.read_text().splitlines()[0].split() == ["4", "3", "0", "0"]
    back = Vocabulary.load(txt)
    np.testing.assert_array_equal(back.descriptors, voc.descriptors)
    np.testing.assert_array_equal(back.weights, voc.weights)
    assert main(["vocab", "train", str(source), "-o", str(tmp_path / "v2.txt"), "--k", "3", "--levels", "2",
                 "--format", "dbow2-txt", "--max-frames", "2"]) == 0
    assert Vocabulary.load_dbow2_text(tmp_path / "v2.txt").k == 3
    assert main(["vocab", "info", str(txt)]) == 0
    assert "k=4, L=3" in capsys.readouterr().out


def test_vocab_train_reports_bad_source(tmp_path, capsys):
    assert main(["vocab", "train", str(tmp_path / "nowhere"), "-o", str(tmp_path / "v.npz")]) == 2
    assert "nowhere" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["vocab", "train", str(tmp_path / "empty"), "-o", str(tmp_path / "v.npz")]) == 2
