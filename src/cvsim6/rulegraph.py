"""Draw Snakemake's rule graph as a PNG without Graphviz.

``snakemake all --rulegraph dot | python -m cvsim6.rulegraph docs/rulegraph.png`` reads the
DOT text Snakemake prints (one ``N[label = "rule", color = "h s v"]`` line per rule, one
``A -> B`` line per dependency) and draws it top-down with a layered (Sugiyama-style)
layout: every rule sits one layer below its lowest input, sources are pulled down next to
the rules that use them, edges spanning several layers pass through dummy points, and the
order within each layer is settled by barycentre sweeps. networkx + matplotlib only, so the
picture can be redrawn on machines without Graphviz's ``dot``.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

import networkx as nx

_NODE = re.compile(r'^\s*(\w+)\s*\[\s*label\s*=\s*"([^"]+)"(?:\s*,\s*color\s*=\s*"([^"]+)")?')
_EDGE = re.compile(r"^\s*(\w+)\s*->\s*(\w+)")


def parse_rulegraph(dot_text: str) -> nx.DiGraph:
    """Rule graph of Snakemake's ``--rulegraph dot`` text: nodes are rule names (attribute
    ``color``: an ``(h, s, v)`` tuple in [0, 1] or None), an edge ``a -> b`` means b uses a."""
    ids: dict[str, str] = {}
    g = nx.DiGraph()
    edges = []
    for line in dot_text.splitlines():
        if m := _EDGE.match(line):
            edges.append((m.group(1), m.group(2)))
        elif m := _NODE.match(line):
            ids[m.group(1)] = m.group(2)
            color = tuple(float(c) for c in m.group(3).split()) if m.group(3) else None
            g.add_node(m.group(2), color=color)
    for a, b in edges:
        if a not in ids or b not in ids:
            raise ValueError(f"rule graph edge {a} -> {b} names a node that is not declared")
        g.add_edge(ids[a], ids[b])
    if g.number_of_nodes() == 0:
        raise ValueError("no rule found in the rule graph text (expected `snakemake --rulegraph dot` output)")
    if not nx.is_directed_acyclic_graph(g):
        raise ValueError("the rule graph has a cycle")
    return g


def assign_layers(g: nx.DiGraph) -> dict[str, int]:
    """Layer (0 = top) of every rule: one below its lowest input (longest path from a
    source); then, bottom-up, every rule with users is pulled down to just above its
    highest user, so a leaf input such as a table rule sits next to the rule that takes it."""
    layer: dict[str, int] = {}
    order = list(nx.topological_sort(g))
    for v in order:
        layer[v] = max((layer[u] + 1 for u in g.predecessors(v)), default=0)
    for v in reversed(order):
        users = list(g.successors(v))
        if users:
            layer[v] = min(layer[w] for w in users) - 1
    return layer


def _layered_with_dummies(g: nx.DiGraph, layer: dict[str, int]):
    """Graph whose edges all span one layer: each long edge a -> b is split by dummy nodes
    ``(a, b, k)``. Returns (graph, layer of every node, chain of nodes of each original edge)."""
    h = nx.DiGraph()
    lay = dict(layer)
    h.add_nodes_from(g.nodes)
    chains = {}
    for a, b in g.edges:
        chain = [a] + [(a, b, k) for k in range(layer[a] + 1, layer[b])] + [b]
        for node in chain[1:-1]:
            lay[node] = node[2]
        nx.add_path(h, chain)
        chains[(a, b)] = chain
    return h, lay, chains


def order_layers(h: nx.DiGraph, lay: dict, sweeps: int = 24) -> list[list]:
    """Order of the nodes in each layer: barycentre heuristic, alternating downward sweeps
    (by the positions of the layer above) and upward sweeps (below), keeping the order with
    the fewest edge crossings."""
    n_layers = max(lay.values()) + 1
    layers: list[list] = [[] for _ in range(n_layers)]
    for v in nx.topological_sort(h):  # deterministic start: discovery order
        layers[lay[v]].append(v)

    def crossings(ls) -> int:
        total = 0
        for upper, lower in zip(ls, ls[1:]):
            pos = {v: i for i, v in enumerate(lower)}
            pairs = sorted((i, pos[w]) for i, v in enumerate(upper) for w in h.successors(v))
            for k, (_, p) in enumerate(pairs):
                total += sum(1 for _, q in pairs[k + 1:] if q < p)
        return total

    best, best_cross = [list(x) for x in layers], crossings(layers)
    for s in range(sweeps):
        down = s % 2 == 0
        rng = range(1, n_layers) if down else range(n_layers - 2, -1, -1)
        for i in rng:
            ref = layers[i - 1] if down else layers[i + 1]
            pos = {v: k for k, v in enumerate(ref)}
            nbrs = h.predecessors if down else h.successors

            def key(item, pos=pos, nbrs=nbrs):
                k, v = item
                p = [pos[u] for u in nbrs(v) if u in pos]
                return (sum(p) / len(p) if p else k, k)
            layers[i] = [v for _, v in sorted(enumerate(layers[i]), key=key)]
        c = crossings(layers)
        if c < best_cross:
            best, best_cross = [list(x) for x in layers], c
    return best


def _isotonic(values: list[float]) -> list[float]:
    """Least-squares non-decreasing fit of ``values`` (pool-adjacent-violators)."""
    blocks: list[list[float]] = []  # [mean, count]
    for v in values:
        blocks.append([v, 1.0])
        while len(blocks) > 1 and blocks[-2][0] > blocks[-1][0]:
            m2, n2 = blocks.pop()
            m1, n1 = blocks.pop()
            blocks.append([(m1 * n1 + m2 * n2) / (n1 + n2), n1 + n2])
    out: list[float] = []
    for m, n in blocks:
        out += [m] * int(n)
    return out


def place_layer(desired: list[float], widths: list[float], gap: float) -> list[float]:
    """Centres closest (least squares) to ``desired`` that keep the layer's order with
    neighbouring boxes at least ``gap`` apart."""
    offset, acc = [], 0.0
    for k, w in enumerate(widths):
        if k:
            acc += (widths[k - 1] + w) / 2 + gap
        offset.append(acc)
    z = _isotonic([d - o for d, o in zip(desired, offset)])
    return [zi + o for zi, o in zip(z, offset)]


def layout(g: nx.DiGraph, char_width: float = 0.062, box_pad: float = 0.25, gap: float = 0.18,
           dummy_width: float = 0.12, passes: int = 30) -> tuple[dict, dict, dict]:
    """Positions (inches) of every rule box centre and dummy point: ``(xy, width, chains)``;
    layers one inch apart, top layer at y = 0. Within the order of :func:`order_layers`,
    each node moves towards the mean x of its neighbours (alternating passes downwards and
    upwards), boxes never closer than ``gap``."""
    layer = assign_layers(g)
    h, lay, chains = _layered_with_dummies(g, layer)
    rows = order_layers(h, lay)
    width = {v: (len(v) * char_width + box_pad if v in g else dummy_width) for row in rows for v in row}
    x = {}
    for row in rows:
        ws = [width[v] for v in row]
        for v, xi in zip(row, place_layer([0.0] * len(row), ws, gap)):
            x[v] = xi
    for p in range(passes):
        seq = rows[1:] if p % 2 == 0 else rows[-2::-1]
        for row in seq:
            desired = []
            for v in row:
                nb = [x[u] for u in (*h.predecessors(v), *h.successors(v))]
                desired.append(sum(nb) / len(nb) if nb else x[v])
            for v, xi in zip(row, place_layer(desired, [width[v] for v in row], gap)):
                x[v] = xi
    xy = {v: (x[v], -float(i)) for i, row in enumerate(rows) for v in row}
    return xy, width, chains


def draw_rulegraph(dot_text: str, png: str | Path, dpi: int = 110) -> nx.DiGraph:
    """Draw the rule graph of ``dot_text`` into ``png``; returns the parsed graph."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import hsv_to_rgb
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch
    from matplotlib.path import Path as MPath

    g = parse_rulegraph(dot_text)
    xy, width, chains = layout(g)
    xs = [p[0] for p in xy.values()]
    ys = [p[1] for p in xy.values()]
    w_in, h_in = max(xs) - min(xs) + 3.0, max(ys) - min(ys) + 1.2
    fig = plt.figure(figsize=(w_in, h_in))
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(min(xs) - 1.5, max(xs) + 1.5)
    ax.set_ylim(min(ys) - 0.6, max(ys) + 0.6)
    ax.set_axis_off()
    box_h = 0.32
    for (a, b), chain in chains.items():
        pts = [xy[v] for v in chain]
        pts[0] = (pts[0][0], pts[0][1] - box_h / 2)
        pts[-1] = (pts[-1][0], pts[-1][1] + box_h / 2)
        if len(pts) == 2:
            path = MPath(pts, [MPath.MOVETO, MPath.LINETO])
        else:  # smooth through the dummy points: quadratic Bezier pieces between midpoints
            verts, codes = [pts[0]], [MPath.MOVETO]
            for p, q in zip(pts[1:-1], pts[2:]):
                verts += [p, ((p[0] + q[0]) / 2, (p[1] + q[1]) / 2)]
                codes += [MPath.CURVE3, MPath.CURVE3]
            verts[-1], codes[-1] = pts[-1], MPath.CURVE3
            path = MPath(verts, codes)
        ax.add_patch(FancyArrowPatch(path=path, arrowstyle="-|>", mutation_scale=9, color="0.65",
                                     lw=1.0, zorder=1))
    for v in g.nodes:
        x, y = xy[v]
        hsv = g.nodes[v]["color"]
        edge = hsv_to_rgb(hsv) if hsv else (0.3, 0.3, 0.3)
        w = width[v]
        ax.add_patch(FancyBboxPatch((x - w / 2, y - box_h / 2), w, box_h,
                                    boxstyle="round,pad=0,rounding_size=0.08", fc="white", ec=edge,
                                    lw=1.6, zorder=2))
        ax.text(x, y, v, ha="center", va="center", fontsize=8, family="sans-serif", zorder=3)
    fig.savefig(png, dpi=dpi, facecolor="white")
    plt.close(fig)
    return g


def main(argv: list[str] | None = None) -> int:
    """``python -m cvsim6.rulegraph OUT.png [IN.dot]`` (DOT text from stdin without IN.dot)."""
    argv = sys.argv[1:] if argv is None else argv
    if not 1 <= len(argv) <= 2:
        print("usage: snakemake all --rulegraph dot | python -m cvsim6.rulegraph OUT.png [IN.dot]",
              file=sys.stderr)
        return 2
    text = Path(argv[1]).read_text() if len(argv) == 2 else sys.stdin.read()
    g = draw_rulegraph(text, argv[0])
    print(f"{argv[0]}: {g.number_of_nodes()} rules, {g.number_of_edges()} dependencies")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
