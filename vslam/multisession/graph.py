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
