"""Place recognition and loop closing.

Building blocks (Galvez-Lopez & Tardos 2012, DBoW2; Mur-Artal et al. 2015, ORB-SLAM):

* :mod:`vslam.loop.vocabulary` -- bag-of-binary-words vocabulary tree (:class:`Vocabulary`,
  :class:`BowVector`, :func:`l1_score`, :func:`load_default_vocabulary`,
  :func:`build_default_vocabulary`). The packaged default (k=10, L=4, ~10^4 words, 350 KB) is
  trained from scikit-image's sample photographs, so nothing is downloaded.
* :mod:`vslam.map.database` -- inverted-index :class:`KeyframeDatabase` with normalized scores.
* :mod:`vslam.loop.detector` -- :class:`LoopDetector`, temporal-consistency groups.
* :mod:`vslam.loop.training` -- ORB descriptors for training (:func:`extract_orb`).
* :mod:`vslam.loop.verification` -- geometric verification (descriptor matching, 3D-3D / Sim(3) or
  PnP RANSAC, guided matching, pose refinement).
* :mod:`vslam.loop.closing` -- :class:`LoopCloser`: detection, verification, fusion, essential-graph
  correction and global BA, as a keyframe listener of the System.
* :mod:`vslam.loop.relocalization` -- :class:`Relocalizer`: localize a lost frame against the map.

(``closing`` and ``relocalization`` are not imported here: import them from their modules.)
"""
from vslam.loop.config import (
    ClosingConfig, DatabaseConfig, LoopConfig, LoopDetectorConfig, RelocalizationConfig, VocabularyConfig,
)
from vslam.map.database import KeyframeDatabase
from vslam.loop.detector import LoopCandidate, LoopDetector
from vslam.loop.vocabulary import (
    DEFAULT_VOCABULARY_PATH,
    BowVector,
    Vocabulary,
    build_default_vocabulary,
    l1_score,
    load_default_vocabulary,
)

__all__ = [
    "BowVector", "ClosingConfig", "DEFAULT_VOCABULARY_PATH", "DatabaseConfig", "RelocalizationConfig", "KeyframeDatabase", "LoopCandidate", "LoopConfig",
    "LoopDetector", "LoopDetectorConfig", "Vocabulary", "VocabularyConfig", "build_default_vocabulary",
    "l1_score", "load_default_vocabulary",
]
