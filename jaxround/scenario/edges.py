"""The ids of a roundabout's edges: the contract between the SUMO files
(`jaxround.sumo_files.netconvert`) and the JAX network compiler.

- edge ``in_{i}`` (``o{i} -> c{i}``), ``out_{i}`` (``c{i} -> o{i}``);
- edge ``ring_{i}`` (``c{i} -> c{i+1}``, counter-clockwise, right-hand traffic).
"""

from __future__ import annotations


def in_edge(leg: int) -> str:
    return f"in_{leg}"


def out_edge(leg: int) -> str:
    return f"out_{leg}"


def ring_edge(leg: int) -> str:
    """The ring edge that starts at leg `leg`'s junction."""
    return f"ring_{leg}"


def route_edges(origin: int, destination: int, n_legs: int) -> list[str]:
    """Edges driven from leg `origin` to leg `destination`, counter-clockwise."""
    edges = [in_edge(origin)]
    leg = origin
    while leg != destination:
        edges.append(ring_edge(leg))
        leg = (leg + 1) % n_legs
    edges.append(out_edge(destination))
    return edges
