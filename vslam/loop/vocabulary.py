"""Bag-of-binary-words vocabulary tree (DBoW2).

Implements Galvez-Lopez & Tardos, "Bags of Binary Words for Fast Place Recognition in Image
Sequences", IEEE T-RO 2012:

* sec. IV: the vocabulary is a tree of branching factor ``k`` and depth ``L`` built by
  hierarchical k-means on binary descriptors. For binary descriptors the centroid of a cluster is
  the bitwise majority vote of its members ("k-majority"), distances are Hamming distances, and
  the initial centroids are chosen by k-means++ (Arthur & Vassilvitskii 2007).
* eq. (1)-(2): each word (leaf) carries an inverse document frequency weight
  ``idf_i = log(N / n_i)`` (``N`` training images, ``n_i`` of them containing word ``i``); an
  image's BoW vector sums ``tf * idf`` per word and is L1-normalized.
* eq. (3): two BoW vectors are compared with the L1 score
  ``s(v1, v2) = 1 - 0.5 * | v1/|v1| - v2/|v2| |_1``, which for L1-normalized non-negative vectors
  equals ``sum_i min(v1_i, v2_i)``.
* sec. V-B: the "direct index" keeps, per feature, its node at a chosen tree level so that
  geometric verification matches features only within the same node.

The tree is stored as flat arrays (node 0 is the root; parents always precede their children and
the children of a node are contiguous), so a frame's descriptors descend the tree in one compiled
loop (:mod:`vslam.loop.vocabulary_kernels`; the NumPy version, one gather of the ``k`` children's
descriptors, one XOR and one popcount per level for all features at once, is the reference).

Example:
    >>> voc = load_default_vocabulary()                      # doctest: +SKIP
    >>> bow, feature_nodes = voc.transform(descriptors)       # doctest: +SKIP
    >>> voc.score(bow, other_bow)                             # doctest: +SKIP
"""
from __future__ import annotations

import functools
import io
import json
import zipfile
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from vslam.errors import ConfigError, MapFormatError, VslamError
from vslam.loop.config import VocabularyConfig
from vslam.loop.vocabulary_kernels import descend_numpy, descend_words
from vslam.map.database import BowVector  # the vector type the keyframe database indexes
from vslam.outputs import atomic_write_bytes, atomic_write_text

log = logging.getLogger(__name__)

FORMAT_NAME = "vslam-bow-vocabulary"
FORMAT_VERSION = 1
DEFAULT_VOCABULARY_PATH = Path(__file__).resolve().parents[1] / "data" / "orb_vocabulary_k10_L4.npz"


# ----------------------------------------------------------------------------- Hamming helpers
def _words(descriptors: np.ndarray) -> np.ndarray:
    """View ``(N, D)`` uint8 descriptors as 64-bit words when ``D % 8 == 0`` (4 popcounts for ORB)."""
    descriptors = np.ascontiguousarray(descriptors, dtype=np.uint8)
    if descriptors.shape[1] % 8 == 0:
        return descriptors.view(np.uint64)
    return descriptors


def _hamming_to_one(words: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Hamming distances ``(N,)`` between ``(N, W)`` packed descriptors and one ``(W,)`` descriptor."""
    return np.bitwise_count(words ^ center).sum(axis=1, dtype=np.int32)


def hamming_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise Hamming distances ``(N, M)`` between ``(N, D)`` and ``(M, D)`` uint8 descriptors."""
    wa, wb = _words(a), _words(b)
    return np.bitwise_count(wa[:, None, :] ^ wb[None, :, :]).sum(axis=2, dtype=np.int32)


# ----------------------------------------------------------------------------- BoW vector
def l1_score(a: BowVector, b: BowVector) -> float:
    """L1 score of eq. (3): ``1 - 0.5 |a - b|_1 = sum_i min(a_i, b_i)`` for L1-normalized vectors, in [0, 1]."""
    common, ia, ib = np.intersect1d(a.words, b.words, assume_unique=True, return_indices=True)
    if common.size == 0:
        return 0.0
    return float(np.minimum(a.values[ia], b.values[ib]).sum())


# ----------------------------------------------------------------------------- vocabulary
class Vocabulary:
    """A trained vocabulary tree with idf word weights.

    Arrays (``n`` nodes, node 0 = root, parents before children, siblings contiguous):
        descriptors: ``(n, D)`` uint8 node centroids (the root's is zeros).
        parents: ``(n,)`` int32, -1 for the root.
        weights: ``(n,)`` float64 idf weight of each word node (0 for inner nodes).

    Derived: ``children (n, k)`` int32 padded with -1, ``depth (n,)``, ``word_of_node (n,)`` (-1 for
    inner nodes; leaves are numbered by increasing node id, as DBoW2 numbers them on loading a text
    file) and ``node_of_word (n_words,)``.
    """

    def __init__(self, k: int, levels: int, descriptors: np.ndarray, parents: np.ndarray, weights: np.ndarray,
                 direct_index_level: int = 2) -> None:
        descriptors = np.ascontiguousarray(descriptors, dtype=np.uint8)
        parents = np.asarray(parents, dtype=np.int32)
        weights = np.asarray(weights, dtype=np.float64)
        n = parents.shape[0]
        if descriptors.ndim != 2 or descriptors.shape[0] != n or weights.shape != (n,) or n < 2:
            raise MapFormatError(
                f"vocabulary arrays disagree: {descriptors.shape} descriptors, {parents.shape} parents, "
                f"{weights.shape} weights (need one row per node and at least one word)"
            )
        if parents[0] != -1 or np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, n)):
            raise MapFormatError("vocabulary tree is malformed: every node's parent must come before it")
        self.k = int(k)
        self.levels = int(levels)
        self.descriptors = descriptors
        self.parents = parents
        self.weights = weights
        self.direct_index_level = int(direct_index_level)

        # children table: stable sort by parent keeps siblings in node-id order
        child_ids = np.arange(1, n, dtype=np.int32)
        order = np.argsort(parents[1:], kind="stable")
        sorted_parents = parents[1:][order]
        n_children = np.bincount(sorted_parents, minlength=n)
        if n_children.max() > self.k:
            raise MapFormatError(f"vocabulary node has {n_children.max()} children but k = {self.k}")
        first = np.concatenate([[0], np.cumsum(n_children)[:-1]])
        slot = np.arange(n - 1) - first[sorted_parents]
        self.children = np.full((n, self.k), -1, dtype=np.int32)
        self.children[sorted_parents, slot] = child_ids[order]

        depth = np.zeros(n, dtype=np.int16)
        for _ in range(self.levels + 1):  # after d passes every node of depth <= d is right
            depth[1:] = depth[parents[1:]] + 1
        self.depth = depth
        if depth.max() > self.levels:
            raise MapFormatError(f"vocabulary tree is {depth.max()} levels deep but L = {self.levels}")
        is_leaf = n_children == 0
        is_leaf[0] = False
        self.node_of_word = np.flatnonzero(is_leaf).astype(np.int32)
        self.word_of_node = np.full(n, -1, dtype=np.int32)
        self.word_of_node[self.node_of_word] = np.arange(self.node_of_word.size, dtype=np.int32)
        self._node_words = _words(descriptors)
        # descent table: missing children repeat the first child (argmin keeps the first of equal
        # distances, so the pick is unchanged) and a leaf's children are itself (it stays put)
        table = np.where(self.children >= 0, self.children, self.children[:, :1])
        table[is_leaf] = np.flatnonzero(is_leaf)[:, None]
        self._descend_children = np.ascontiguousarray(table)

    # ------------------------------------------------------------------ properties
    @property
    def n_nodes(self) -> int:
        return int(self.parents.shape[0])

    @property
    def n_words(self) -> int:
        return int(self.node_of_word.shape[0])

    @property
    def descriptor_size(self) -> int:
        return int(self.descriptors.shape[1])

    @property
    def word_weights(self) -> np.ndarray:
        """``(n_words,)`` idf weight per word."""
        return self.weights[self.node_of_word]

    def __repr__(self) -> str:
        return (f"Vocabulary(k={self.k}, L={self.levels}, words={self.n_words}, nodes={self.n_nodes}, "
                f"descriptor_bytes={self.descriptor_size})")

    # ------------------------------------------------------------------ lookup
    def descend(self, descriptors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Push descriptors down the tree, all at once, level by level.

        Args:
            descriptors: ``(N, D)`` uint8.
        Returns:
            ``leaf_nodes (N,)`` int32 and ``path (L + 1, N)`` int32: ``path[l]`` is each feature's
            node at level ``l`` (a feature that reached a leaf early stays on it).
        """
        descriptors = np.asarray(descriptors)
        if descriptors.ndim != 2 or descriptors.shape[1] != self.descriptor_size:
            raise VslamError(
                f"descriptors of shape {descriptors.shape} do not fit this vocabulary "
                f"({self.descriptor_size}-byte descriptors expected)"
            )
        query = _words(descriptors)
        if query.dtype == np.uint64 and len(query):  # compiled: the same integer distances and first-minimum picks
            path = np.zeros((self.levels + 1, len(query)), dtype=np.int32)
            descend_words(self._node_words, self._descend_children, query, self.levels, path)
            return path[-1].copy(), path
        return descend_numpy(self._node_words, self._descend_children, query, self.levels)

    def transform(self, descriptors: np.ndarray | None, direct_index_level: int | None = None
                  ) -> tuple[BowVector, np.ndarray]:
        """BoW vector (tf-idf, L1-normalized, eq. (1)-(2)) and direct index of a frame's descriptors.

        Args:
            descriptors: ``(N, D)`` uint8.
            direct_index_level: tree level of the direct index (default: ``self.direct_index_level``).
        Returns:
            ``(bow, feature_nodes)``: ``feature_nodes (N,)`` int32 is each feature's node id at the
            direct-index level; features with equal ids may match each other.
        """
        level = self.direct_index_level if direct_index_level is None else int(direct_index_level)
        if not 0 <= level <= self.levels:
            raise ConfigError(f"direct_index_level={level}: must be in 0..{self.levels}")
        if descriptors is None or len(descriptors) == 0:  # OpenCV returns None when it finds no keypoint
            return BowVector(np.zeros(0, np.int32), np.zeros(0)), np.zeros(0, np.int32)
        leaves, path = self.descend(descriptors)
        return self._bow_from_leaves(leaves), path[level].copy()

    def words_of(self, descriptors: np.ndarray) -> np.ndarray:
        """``(N,)`` word id of each descriptor."""
        return self.word_of_node[self.descend(descriptors)[0]]

    def _bow_from_leaves(self, leaves: np.ndarray) -> BowVector:
        weights = self.weights[leaves]
        keep = weights > 0  # words seen in every training image carry no information
        words = self.word_of_node[leaves[keep]]
        if words.size == 0:
            return BowVector(np.zeros(0, np.int32), np.zeros(0))
        unique, inverse = np.unique(words, return_inverse=True)
        values = np.bincount(inverse, weights=weights[keep])
        values /= values.sum()
        return BowVector(unique.astype(np.int32), values)

    @staticmethod
    def score(a: BowVector, b: BowVector) -> float:
        """L1 similarity of eq. (3), in [0, 1]."""
        return l1_score(a, b)

    # ------------------------------------------------------------------ training
    @classmethod
    def train(cls, descriptor_sets: Sequence[np.ndarray], config: VocabularyConfig = VocabularyConfig(),
              progress=None) -> Vocabulary:
        """Train a vocabulary from per-image descriptor arrays (sec. IV).

        Hierarchical k-majority clustering with k-means++ seeding builds the tree; then every
        training image is transformed with the tree and ``idf_i = log(N / n_i)`` is set per word.

        Args:
            descriptor_sets: one ``(N_i, D)`` uint8 array per training image.
            config: branching factor, depth, iterations, seed.
            progress: a tqdm-like factory (``progress(total=, desc=)`` returning a bar with
                ``update(n)`` and ``close()``); the bar counts descriptors clustered, ``levels``
                times the descriptor count in all. None shows nothing.
        """
        sets = [np.asarray(d, dtype=np.uint8) for d in descriptor_sets if len(d)]
        if not sets:
            raise VslamError("cannot train a vocabulary: no descriptors were given (no images or no features)")
        sizes = {d.shape[1] for d in sets}
        if len(sizes) != 1:
            raise VslamError(f"cannot train a vocabulary from descriptors of different sizes {sorted(sizes)}")
        all_desc = np.concatenate(sets)
        log.info("training vocabulary k=%d L=%d on %d descriptors from %d images",
                 config.k, config.levels, all_desc.shape[0], len(sets))
        bar = progress(total=config.levels * all_desc.shape[0], desc="vocabulary", unit="desc") if progress else None
        try:
            descriptors, parents = _build_tree(all_desc, config, bar.update if bar is not None else None)
        finally:
            if bar is not None:
                bar.close()
        weights = np.zeros(parents.shape[0])
        voc = cls(config.k, config.levels, descriptors, parents, weights, config.direct_index_level)
        image_of = np.repeat(np.arange(len(sets)), [len(d) for d in sets])
        words = voc.word_of_node[voc.descend(all_desc)[0]]
        pairs = np.unique(image_of.astype(np.int64) * voc.n_words + words)
        n_images_with_word = np.bincount(pairs % voc.n_words, minlength=voc.n_words)
        idf = np.zeros(voc.n_words)
        seen = n_images_with_word > 0
        idf[seen] = np.log(len(sets) / n_images_with_word[seen])
        voc.weights[voc.node_of_word] = idf
        log.info("vocabulary trained: %d words (%d never visited by the training data)", voc.n_words, (~seen).sum())
        return voc

    # ------------------------------------------------------------------ I/O
    def save(self, path: str | Path) -> Path:
        """Save as compressed ``.npz``: tree arrays plus a JSON header (format, version, k, L, sizes)."""
        path = Path(path)
        header = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "k": self.k, "levels": self.levels,
                  "descriptor_size": self.descriptor_size, "n_nodes": self.n_nodes, "n_words": self.n_words,
                  "direct_index_level": self.direct_index_level, "scoring": "L1", "weighting": "TF-IDF"}
        path.parent.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        np.savez_compressed(buf, header=np.array(json.dumps(header)), descriptors=self.descriptors,
                            parents=self.parents, weights=self.weights)
        return atomic_write_bytes(path, buf.getvalue())  # a full disk leaves an existing file whole

    @classmethod
    def load(cls, path: str | Path) -> Vocabulary:
        """Load a vocabulary saved by :meth:`save` (or a DBoW2 text file, by extension ``.txt``)."""
        path = Path(path)
        if path.suffix == ".txt":
            return cls.load_dbow2_text(path)
        if not path.is_file():
            raise MapFormatError(f"vocabulary file {path} does not exist (train one with `vslam vocab train`)")
        try:
            with np.load(path, allow_pickle=False) as data:
                header = json.loads(str(data["header"]))
                descriptors, parents, weights = data["descriptors"], data["parents"], data["weights"]
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise MapFormatError(f"vocabulary file {path} is not a vslam vocabulary (.npz): {exc}") from exc
        if header.get("format") != FORMAT_NAME:
            raise MapFormatError(f"vocabulary file {path}: unknown format {header.get('format')!r}")
        if header.get("version") != FORMAT_VERSION:
            raise MapFormatError(
                f"vocabulary file {path} has version {header.get('version')}, this vslam reads version "
                f"{FORMAT_VERSION}: retrain it with `vslam vocab train`"
            )
        return cls(header["k"], header["levels"], descriptors, parents, weights,
                   header.get("direct_index_level", 2))

    def save_dbow2_text(self, path: str | Path) -> Path:
        """Export in DBoW2's text format (``ORBvoc.txt``, read by ORB-SLAM2/3 ``loadFromTextFile``).

        Line 1: ``k L scoring weighting`` (0 0 = L1 norm, TF-IDF). Then one line per node except the
        root, in node-id order: ``parent_id is_leaf byte_0 ... byte_{D-1} weight``.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        is_leaf = self.word_of_node >= 0
        lines = [f"{self.k} {self.levels} 0 0"]
        for i in range(1, self.n_nodes):
            desc = " ".join(map(str, self.descriptors[i].tolist()))
            lines.append(f"{self.parents[i]} {int(is_leaf[i])} {desc} {float(self.weights[i])!r}")
        return atomic_write_text(path, "\n".join(lines) + "\n")

    @classmethod
    def load_dbow2_text(cls, path: str | Path, descriptor_size: int = 32) -> Vocabulary:
        """Read a DBoW2 text vocabulary (the format of :meth:`save_dbow2_text` and ``ORBvoc.txt``)."""
        path = Path(path)
        if not path.is_file():
            raise MapFormatError(f"DBoW2 vocabulary {path} does not exist")
        with open(path) as fh:
            first = fh.readline().split()
            body = fh.read()
        try:
            k, levels, scoring, weighting = (int(x) for x in first[:4])
        except ValueError as exc:
            raise MapFormatError(f"DBoW2 vocabulary {path}: first line must be 'k L scoring weighting'") from exc
        if not (2 <= k <= 20 and 1 <= levels <= 10 and scoring == 0 and weighting == 0):
            raise MapFormatError(
                f"DBoW2 vocabulary {path}: k={k} L={levels} scoring={scoring} weighting={weighting} "
                "(vslam reads L1-norm scoring and TF-IDF weighting, k in 2..20, L in 1..10)"
            )
        values = np.array(body.split(), dtype=np.float64)
        width = descriptor_size + 3
        if values.size % width:
            raise MapFormatError(f"DBoW2 vocabulary {path}: node lines must hold {width} numbers each")
        rows = values.reshape(-1, width)
        parents = np.concatenate([[-1], rows[:, 0].astype(np.int32)])
        descriptors = np.concatenate([np.zeros((1, descriptor_size), np.uint8), rows[:, 2:-1].astype(np.uint8)])
        weights = np.concatenate([[0.0], rows[:, -1]])
        voc = cls(k, levels, descriptors, parents, weights)
        if not np.array_equal(voc.word_of_node[1:] >= 0, rows[:, 1] > 0):
            raise MapFormatError(f"DBoW2 vocabulary {path}: leaf flags disagree with the tree")
        return voc


# ----------------------------------------------------------------------------- k-majority tree
def _kmeanspp_seeds(words: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``k`` k-means++ seeds (Arthur & Vassilvitskii 2007) with Hamming distances.

    Greedy variant: each step draws ``2 + ln k`` candidates by D^2 sampling and keeps the one that
    lowers the potential most, which rarely leaves a cluster unseeded.
    """
    n = words.shape[0]
    trials = 2 + int(np.log(k))
    seeds = [int(rng.integers(n))]
    dist = _hamming_to_one(words, words[seeds[0]]).astype(np.float64)
    for _ in range(1, k):
        prob = dist * dist
        total = prob.sum()
        if total <= 0:  # every remaining descriptor equals a seed
            break
        candidates = rng.choice(n, size=trials, p=prob / total)
        best_pot, best_idx, best_dist = np.inf, -1, dist
        for c in candidates:
            new_dist = np.minimum(dist, _hamming_to_one(words, words[c]))
            potential = float((new_dist * new_dist).sum())
            if potential < best_pot:
                best_pot, best_idx, best_dist = potential, int(c), new_dist
        seeds.append(best_idx)
        dist = best_dist
    return np.array(seeds)


def _kmajority(descriptors: np.ndarray, k: int, max_iterations: int, rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray]:
    """Cluster binary descriptors: k-means++ seeds, then Hamming assignment / bitwise majority vote.

    Returns ``(centers (c, D) uint8, labels (N,))`` with ``c <= k`` non-empty clusters.
    """
    n = descriptors.shape[0]
    if n <= k:
        return descriptors.copy(), np.arange(n)
    words = _words(descriptors)
    centers = descriptors[_kmeanspp_seeds(words, k, rng)]
    labels = None
    for _ in range(max_iterations):
        center_words = _words(centers)
        dist = np.stack([_hamming_to_one(words, c) for c in center_words], axis=1)
        new_labels = dist.argmin(axis=1)
        if labels is not None and np.array_equal(new_labels, labels):
            break
        labels = new_labels
        present = np.unique(labels)
        new_centers = np.empty((present.size, descriptors.shape[1]), np.uint8)
        for j, c in enumerate(present):
            members = np.unpackbits(descriptors[labels == c], axis=1)
            new_centers[j] = np.packbits(2 * members.sum(axis=0, dtype=np.int64) > members.shape[0])
        centers = new_centers
        labels = np.searchsorted(present, labels)
    center_words = _words(centers)
    labels = np.stack([_hamming_to_one(words, c) for c in center_words], axis=1).argmin(axis=1)
    keep = np.unique(labels)
    return centers[keep], np.searchsorted(keep, labels)


def _build_tree(descriptors: np.ndarray, config: VocabularyConfig, done=None) -> tuple[np.ndarray, np.ndarray]:
    """Hierarchical k-majority, breadth first so siblings get contiguous ids (DBoW2 HKmeansStep).

    A cluster is split again while its level is below ``L`` and it holds more than one descriptor.
    ``done(n)``, when given, is called with the number of descriptors of each cluster split.
    """
    rng = np.random.default_rng(config.seed)
    node_desc = [np.zeros(descriptors.shape[1], np.uint8)]
    parents = [-1]
    queue = [(0, np.arange(descriptors.shape[0]), 0)]
    head = 0
    while head < len(queue):
        node, members, level = queue[head]
        head += 1
        centers, labels = _kmajority(descriptors[members], config.k, config.max_iterations, rng)
        if done is not None:
            done(int(members.size))
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(centers.shape[0] + 1))
        for j in range(centers.shape[0]):
            child = len(parents)
            parents.append(node)
            node_desc.append(centers[j])
            child_members = members[order[bounds[j]:bounds[j + 1]]]
            if level + 1 < config.levels and child_members.size > 1:
                queue.append((child, child_members, level + 1))
    return np.stack(node_desc), np.array(parents, dtype=np.int32)


# ----------------------------------------------------------------------------- default vocabulary
def build_default_vocabulary(output: str | Path | None = DEFAULT_VOCABULARY_PATH,
                             config: VocabularyConfig = VocabularyConfig(k=10, levels=4),
                             views_per_image: int = 24) -> Vocabulary:
    """Regenerate the vocabulary shipped in ``vslam/data`` (no download needed).

    It is trained on ORB descriptors (1000 per image) of the scikit-image sample photographs that
    ship inside the scikit-image wheel, each seen under several deterministic crops, scales,
    rotations and perspective warps (:func:`vslam.loop.training.default_training_descriptors`).
    The result is deterministic for fixed OpenCV / scikit-image versions; the packaged file was
    made with the defaults (480 views, ~340k descriptors, about 30 s of training on one core).

    Regenerate it with::

        python -c "from vslam.loop.vocabulary import build_default_vocabulary; build_default_vocabulary()"

    Args:
        output: where to save the ``.npz`` (default: the packaged file); None to skip saving.
        config: tree shape (default k=10, L=4: <= 10^4 words, ~350 KB).
        views_per_image: warped views per sample image.
    """
    from vslam.loop.training import default_training_descriptors

    voc = Vocabulary.train(default_training_descriptors(views_per_image), config)
    if output is not None:
        voc.save(output)
        log.info("default vocabulary written to %s", output)
    return voc


@functools.lru_cache(maxsize=1)
def load_default_vocabulary() -> Vocabulary:
    """The packaged default vocabulary (loaded once per process)."""
    if not DEFAULT_VOCABULARY_PATH.is_file():
        raise MapFormatError(
            f"the default vocabulary {DEFAULT_VOCABULARY_PATH} is missing from the installation: regenerate it "
            "with `python -c 'from vslam.loop.vocabulary import build_default_vocabulary as b; b()'`"
        )
    return Vocabulary.load(DEFAULT_VOCABULARY_PATH)
