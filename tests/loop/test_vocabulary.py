"""Vocabulary tree: k-majority training, vectorized descent, tf-idf, L1 score, file formats."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from vslam.errors import ConfigError, MapFormatError
from vslam.loop.config import VocabularyConfig
from vslam.loop.vocabulary import (
    DEFAULT_VOCABULARY_PATH,
    BowVector,
    Vocabulary,
    _kmajority,
    hamming_distance,
    l1_score,
)


def clustered_descriptors(rng, n_clusters: int, per_cluster: int, flips: int) -> tuple[np.ndarray, np.ndarray]:
    """Random 256-bit prototypes and members that differ from theirs by ``flips`` random bits."""
    protos = rng.integers(0, 256, (n_clusters, 32), dtype=np.uint8)
    bits = np.repeat(np.unpackbits(protos, axis=1), per_cluster, axis=0)
    for row in bits:
        row[rng.choice(256, flips, replace=False)] ^= 1
    return protos, np.packbits(bits, axis=1)


@pytest.fixture(scope="module")
def small_vocabulary() -> tuple[Vocabulary, list[np.ndarray]]:
    rng = np.random.default_rng(3)
    _, desc = clustered_descriptors(rng, 60, 40, 30)
    sets = np.array_split(desc[rng.permutation(len(desc))], 30)
    return Vocabulary.train(sets, VocabularyConfig(k=5, levels=3, seed=1)), sets


def naive_descend(voc: Vocabulary, d: np.ndarray) -> int:
    """Reference: one descriptor, one node at a time, first child on ties (DBoW2 ``transform``)."""
    node = 0
    while True:
        kids = [c for c in voc.children[node] if c >= 0]
        if not kids:
            return node
        dist = [int(np.unpackbits(d ^ voc.descriptors[c]).sum()) for c in kids]
        node = kids[int(np.argmin(dist))]


def test_hamming_distance_matches_unpacked_bits():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (7, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    expected = (np.unpackbits(a, axis=1)[:, None, :] != np.unpackbits(b, axis=1)[None]).sum(axis=2)
    np.testing.assert_array_equal(hamming_distance(a, b), expected)


def test_kmajority_recovers_prototypes_by_majority_vote():
    rng = np.random.default_rng(1)
    protos, desc = clustered_descriptors(rng, 4, 50, 20)  # 8 % of the bits flipped per member
    centers, labels = _kmajority(desc, 4, 20, np.random.default_rng(0))
    assert centers.shape == (4, 32)
    # every prototype is recovered bit-exactly and every member is labelled with its own cluster
    match = hamming_distance(protos, centers).argmin(axis=1)
    np.testing.assert_array_equal(hamming_distance(protos, centers)[np.arange(4), match], 0)
    assert len(set(match)) == 4
    np.testing.assert_array_equal(labels, np.repeat(match, 50))


def test_tree_shape_and_vectorized_descent_equals_naive(small_vocabulary):
    voc, sets = small_vocabulary
    assert voc.k == 5 and voc.levels == 3
    assert voc.depth.max() == 3 and 60 <= voc.n_words <= 125
    assert np.all(voc.parents[1:] < np.arange(1, voc.n_nodes))
    rng = np.random.default_rng(7)
    queries = np.concatenate([sets[0][:40], rng.integers(0, 256, (40, 32), dtype=np.uint8)])
    leaves, path = voc.descend(queries)
    np.testing.assert_array_equal(leaves, [naive_descend(voc, q) for q in queries])
    assert np.all(voc.word_of_node[leaves] >= 0)
    # the path is a chain of parent links ending at the leaf
    for level in range(1, voc.levels + 1):
        moved = path[level] != path[level - 1]
        np.testing.assert_array_equal(voc.parents[path[level][moved]], path[level - 1][moved])


def test_compiled_descent_equals_numpy_on_ties(vocabulary):
    """The compiled descent (vocabulary_kernels) gives the NumPy descent's leaves and paths exactly,
    also for descriptors equal to node centroids and coarse ones with many equal distances."""
    from vslam.loop.vocabulary import _words
    from vslam.loop.vocabulary_kernels import descend_numpy

    rng = np.random.default_rng(11)
    centroids = vocabulary.descriptors[rng.integers(1, vocabulary.n_nodes, 400)]
    coarse = rng.integers(0, 256, (400, 32), dtype=np.uint8) & np.uint8(0x81)
    queries = np.concatenate([rng.integers(0, 256, (400, 32), dtype=np.uint8), centroids, coarse])
    leaves, path = vocabulary.descend(queries)
    ref_leaves, ref_path = descend_numpy(vocabulary._node_words, vocabulary._descend_children, _words(queries),
                                         vocabulary.levels)
    np.testing.assert_array_equal(leaves, ref_leaves)
    np.testing.assert_array_equal(path, ref_path)
    assert leaves.dtype == ref_leaves.dtype == np.int32
    assert len(np.unique(leaves)) > 300  # the queries spread over the tree


def test_direct_index_node_is_ancestor_of_the_word(small_vocabulary):
    voc, sets = small_vocabulary
    bow, nodes = voc.transform(sets[1], direct_index_level=2)
    leaves, _ = voc.descend(sets[1])
    assert nodes.shape == (len(sets[1]),)
    assert np.all(voc.depth[nodes] <= 2)
    ancestor = leaves.copy()
    while np.any(voc.depth[ancestor] > 2):
        deep = voc.depth[ancestor] > 2
        ancestor[deep] = voc.parents[ancestor[deep]]
    np.testing.assert_array_equal(nodes, ancestor)
    with pytest.raises(ConfigError):
        voc.transform(sets[1], direct_index_level=9)


def test_tf_idf_weights_and_l1_normalized_bow():
    rng = np.random.default_rng(2)
    zeros = np.zeros((10, 32), np.uint8)
    ones = np.full((10, 32), 255, np.uint8)
    noisy = lambda d: d ^ (rng.random(d.shape) < 0.02).astype(np.uint8)  # noqa: E731
    # word "zeros" is in all 4 images (idf log(4/4) = 0), word "ones" in one (idf log 4)
    sets = [noisy(zeros), np.concatenate([noisy(zeros), noisy(ones)]), noisy(zeros), noisy(zeros)]
    voc = Vocabulary.train(sets, VocabularyConfig(k=2, levels=1, direct_index_level=1))
    assert voc.n_words == 2
    w_zero, w_one = voc.weights[voc.descend(np.stack([zeros[0], ones[0]]))[0]]
    assert w_zero == pytest.approx(0.0)
    assert w_one == pytest.approx(np.log(4.0))
    assert len(voc.transform(zeros)[0]) == 0  # only zero-weight words: empty vector
    # tf-idf by hand on a two-word vocabulary with weights 1.0 and 0.5
    hand = Vocabulary(2, 1, np.stack([np.zeros(32, np.uint8), zeros[0], ones[0]]), [-1, 0, 0], [0.0, 1.0, 0.5], 1)
    bow, _ = hand.transform(np.stack([zeros[0], zeros[0], ones[0]]))
    np.testing.assert_array_equal(bow.words, [0, 1])
    np.testing.assert_allclose(bow.values, [2.0 / 2.5, 0.5 / 2.5])


def test_l1_score_is_one_minus_half_l1_distance():
    rng = np.random.default_rng(4)
    for _ in range(20):
        dense = [rng.random(50) * (rng.random(50) < 0.4) for _ in range(2)]
        a, b = (d / d.sum() for d in dense)
        va, vb = (BowVector(np.flatnonzero(x).astype(np.int32), x[x > 0]) for x in (a, b))
        assert l1_score(va, vb) == pytest.approx(1 - 0.5 * np.abs(a - b).sum(), abs=1e-12)
        assert l1_score(va, va) == pytest.approx(1.0)
    disjoint = BowVector(np.array([0, 1], np.int32), np.array([0.5, 0.5]))
    other = BowVector(np.array([2], np.int32), np.array([1.0]))
    assert l1_score(disjoint, other) == 0.0


def test_npz_round_trip_is_exact(small_vocabulary, tmp_path):
    voc, sets = small_vocabulary
    path = voc.save(tmp_path / "voc.npz")
    back = Vocabulary.load(path)
    for name in ("descriptors", "parents", "weights", "children", "word_of_node"):
        np.testing.assert_array_equal(getattr(back, name), getattr(voc, name))
    assert (back.k, back.levels, back.direct_index_level) == (voc.k, voc.levels, voc.direct_index_level)
    b1, n1 = voc.transform(sets[2])
    b2, n2 = back.transform(sets[2])
    np.testing.assert_array_equal(b1.words, b2.words)
    np.testing.assert_array_equal(b1.values, b2.values)
    np.testing.assert_array_equal(n1, n2)


def test_npz_rejects_other_versions_and_garbage(small_vocabulary, tmp_path):
    voc, _ = small_vocabulary
    header = {"format": "vslam-bow-vocabulary", "version": 99, "k": 5, "levels": 3}
    np.savez(tmp_path / "future.npz", header=np.array(json.dumps(header)), descriptors=voc.descriptors,
             parents=voc.parents, weights=voc.weights)
    with pytest.raises(MapFormatError, match="version 99"):
        Vocabulary.load(tmp_path / "future.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(MapFormatError):
        Vocabulary.load(tmp_path / "junk.npz")
    with pytest.raises(MapFormatError, match="does not exist"):
        Vocabulary.load(tmp_path / "missing.npz")


def read_dbow2_text(path) -> dict:
    """A tiny independent reader of DBoW2's text format (as ORB-SLAM's ``loadFromTextFile``)."""
    lines = path.read_text().splitlines()
    k, L, scoring, weighting = map(int, lines[0].split())
    parents, leaf, desc, weight = [-1], [0], [[0] * 32], [0.0]
    for line in lines[1:]:
        tok = line.split()
        assert len(tok) == 35
        parents.append(int(tok[0]))
        leaf.append(int(tok[1]))
        desc.append([int(t) for t in tok[2:34]])
        weight.append(float(tok[34]))
    return {"k": k, "L": L, "scoring": scoring, "weighting": weighting, "parents": np.array(parents),
            "leaf": np.array(leaf), "descriptors": np.array(desc, np.uint8), "weights": np.array(weight)}


def test_dbow2_text_export_parses_back(small_vocabulary, tmp_path):
    voc, sets = small_vocabulary
    path = voc.save_dbow2_text(tmp_path / "voc.txt")
    parsed = read_dbow2_text(path)
    assert (parsed["k"], parsed["L"], parsed["scoring"], parsed["weighting"]) == (5, 3, 0, 0)
    np.testing.assert_array_equal(parsed["parents"], voc.parents)
    np.testing.assert_array_equal(parsed["descriptors"], voc.descriptors)
    np.testing.assert_array_equal(parsed["weights"], voc.weights)
    np.testing.assert_array_equal(parsed["leaf"][1:] == 1, voc.word_of_node[1:] >= 0)
    assert np.all(parsed["parents"][1:] < np.arange(1, len(parsed["parents"])))  # parents come first
    # DBoW2 numbers words by the order their leaves appear: the same ids as ours
    back = Vocabulary.load(path)
    np.testing.assert_array_equal(back.node_of_word, voc.node_of_word)
    np.testing.assert_array_equal(back.words_of(sets[3]), voc.words_of(sets[3]))


def test_dbow2_text_rejects_other_scoring(tmp_path):
    (tmp_path / "l2.txt").write_text("10 6 1 0\n")
    with pytest.raises(MapFormatError, match="scoring=1"):
        Vocabulary.load_dbow2_text(tmp_path / "l2.txt")


def test_default_vocabulary_is_small_and_loads_fast():
    size = DEFAULT_VOCABULARY_PATH.stat().st_size
    t0 = time.perf_counter()
    voc = Vocabulary.load(DEFAULT_VOCABULARY_PATH)
    load_s = time.perf_counter() - t0
    assert size < 1024 * 1024
    assert load_s < 1.0
    assert (voc.k, voc.levels, voc.descriptor_size) == (10, 4, 32)
    assert voc.n_words > 9000
    assert np.all(voc.word_weights >= 0) and np.count_nonzero(voc.word_weights) > 0.99 * voc.n_words


def test_transform_of_1000_descriptors_is_fast(vocabulary):
    rng = np.random.default_rng(5)
    desc = rng.integers(0, 256, (1000, 32), dtype=np.uint8)
    vocabulary.transform(desc)
    best = min(_timed(lambda: vocabulary.transform(desc)) for _ in range(15))
    assert best < 0.010, f"transform of 1000 descriptors took {best * 1e3:.1f} ms (target 5 ms)"


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def test_default_training_views_are_deterministic():
    from vslam.loop.training import default_training_images

    first = [img for _, img in zip(range(3), default_training_images(views_per_image=2, seed=0))]
    again = [img for _, img in zip(range(3), default_training_images(views_per_image=2, seed=0))]
    for a, b in zip(first, again):
        assert a.shape == (480, 640) and a.dtype == np.uint8
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0], first[1])


def test_config_validation():
    with pytest.raises(ConfigError, match="k=1"):
        VocabularyConfig(k=1)
    with pytest.raises(ConfigError, match="direct_index_level"):
        VocabularyConfig(levels=2, direct_index_level=3)


def test_build_default_vocabulary_is_reproducible(tmp_path):
    """A reduced run of the recipe that made the packaged vocabulary (1 view per sample image)."""
    from vslam.loop.vocabulary import build_default_vocabulary

    config = VocabularyConfig(k=4, levels=2)
    a = build_default_vocabulary(tmp_path / "a.npz", config, views_per_image=1)
    b = build_default_vocabulary(None, config, views_per_image=1)
    assert a.n_words == 16 and np.count_nonzero(a.word_weights) >= 12
    np.testing.assert_array_equal(a.descriptors, b.descriptors)
    np.testing.assert_array_equal(a.weights, b.weights)
    assert Vocabulary.load(tmp_path / "a.npz").n_words == 16


def test_transform_of_no_descriptors_is_empty(small_vocabulary):
    voc, _ = small_vocabulary
    for empty in (None, np.zeros((0, 32), np.uint8)):
        bow, nodes = voc.transform(empty)
        assert len(bow) == 0 and nodes.shape == (0,)


def test_training_progress_counts_descriptors_per_level():
    """The bar's total is levels x descriptors; each split adds its cluster's size (the last
    level's clusters are leaves and are not split)."""
    rng = np.random.default_rng(4)
    _, desc = clustered_descriptors(rng, 8, 20, 30)
    sets = np.array_split(desc, 8)
    bars = []

    class Bar:
        def __init__(self, total, desc, unit):
            self.total, self.n, self.closed = total, 0, False
            bars.append(self)

        def update(self, n):
            self.n += n

        def close(self):
            self.closed = True

    voc = Vocabulary.train(sets, VocabularyConfig(k=4, levels=2, seed=1), progress=Bar)
    plain = Vocabulary.train(sets, VocabularyConfig(k=4, levels=2, seed=1))
    assert np.array_equal(voc.descriptors, plain.descriptors)
    (bar,) = bars
    assert bar.total == 2 * 160 and bar.closed
    assert 160 + 150 <= bar.n <= 2 * 160  # the root (160) and its 4 children (all but singletons)
