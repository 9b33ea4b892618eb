"""The session graph: connected components and the spanning tree of the strongest overlaps."""
from __future__ import annotations


class _Forest:
    """Disjoint sets of session names (union-find with path halving)."""

    def __init__(self, names: list[str]) -> None:
        self.parent = {n: n for n in names}

    def find(self, x: str) -> str:
        parent = self.parent
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    def union(self, a: str, b: str) -> bool:
        """Join the sets of ``a`` and ``b``; False when they were one set already."""
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        self.parent[ra] = rb
        return True


def components(names: list[str], edges: list[dict]) -> list[list[str]]:
    """Connected components of ``names`` under ``edges`` (``{a, b}``), largest first (ties: by name);
    names inside a component keep the order of ``names``."""
    forest = _Forest(names)
    for e in edges:
        if e["a"] in forest.parent and e["b"] in forest.parent:
            forest.union(e["a"], e["b"])
    groups: dict[str, list[str]] = {}
    for n in names:
        groups.setdefault(forest.find(n), []).append(n)
    return sorted(groups.values(), key=lambda g: (-len(g), g[0]))


def spanning_tree(names: list[str], edges: list[dict]) -> list[dict]:
    """Kruskal's maximum spanning tree (forest) by ``inliers``: the strongest overlaps that connect
    every session of a component once."""
    forest = _Forest(names)
    tree = []
    for e in sorted(edges, key=lambda e: (-e["inliers"], e["a"], e["b"])):
        if e["a"] in forest.parent and e["b"] in forest.parent and forest.union(e["a"], e["b"]):
            tree.append(e)
    return tree


def forest_matching(tree: list[dict]) -> list[dict]:
    """A maximum matching of a forest's edges (``{a, b, inliers}``): repeatedly the strongest edge
    at a leaf (a node with one edge left), whose two ends then leave the forest. A leaf matched to
    its only neighbour belongs to some maximum matching, so the greedy is maximum: a chain of ``2k``
    nodes gives all ``k`` pairs, where taking the strongest edges first can leave ``k - 1``
    (Karp and Sipser's leaf rule, exact on forests)."""
    degree: dict = {}
    for t in tree:
        for v in (t["a"], t["b"]):
            degree[v] = degree.get(v, 0) + 1
    left, out = list(tree), []
    while left:
        t = min((e for e in left if degree[e["a"]] == 1 or degree[e["b"]] == 1),
                key=lambda e: (-e["inliers"], e["a"], e["b"]))
        out.append(t)
        gone = {t["a"], t["b"]}
        kept = []
        for e in left:
            if e["a"] in gone or e["b"] in gone:
                degree[e["a"]] -= 1
                degree[e["b"]] -= 1
            else:
                kept.append(e)
        left = kept
    return out
