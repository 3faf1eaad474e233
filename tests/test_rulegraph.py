"""The Graphviz-free rule-graph drawer (cvsim6.rulegraph)."""
import matplotlib.image as mpimg
import pytest

from cvsim6 import rulegraph

DOT = """digraph snakemake_dag {
    graph[bgcolor=white, margin=0];
    node[shape=box, style=rounded, fontname=sans,                 fontsize=10, penwidth=2];
    edge[penwidth=2, color=grey];
	0[label = "all", color = "0.00 0.6 0.85", style="rounded"];
	1[label = "table", color = "0.25 0.6 0.85", style="rounded"];
	2[label = "sample", color = "0.50 0.6 0.85", style="rounded"];
	3[label = "simulate", color = "0.75 0.6 0.85", style="rounded"];
	4[label = "train", color = "0.40 0.6 0.85", style="rounded"];
	1 -> 0
	2 -> 3
	3 -> 4
	3 -> 0
	4 -> 0
}
"""


def test_parse_reads_rules_colours_and_dependencies():
    g = rulegraph.parse_rulegraph(DOT)
    assert set(g.nodes) == {"all", "table", "sample", "simulate", "train"}
    assert set(g.edges) == {("table", "all"), ("sample", "simulate"), ("simulate", "train"),
                            ("simulate", "all"), ("train", "all")}
    assert g.nodes["simulate"]["color"] == (0.75, 0.6, 0.85)


@pytest.mark.parametrize("text, message", [
    ("digraph {}", "no rule found"),
    ('0[label = "a"];\n0 -> 7', "not declared"),
    ('0[label = "a"];\n1[label = "b"];\n0 -> 1\n1 -> 0', "cycle"),
])
def test_parse_rejects_bad_text(text, message):
    with pytest.raises(ValueError, match=message):
        rulegraph.parse_rulegraph(text)


def test_layers_put_each_rule_below_its_inputs_and_pull_leaf_inputs_down():
    g = rulegraph.parse_rulegraph(DOT)
    layer = rulegraph.assign_layers(g)
    assert layer == {"sample": 0, "simulate": 1, "train": 2, "all": 3, "table": 2}
    assert all(layer[b] > layer[a] for a, b in g.edges)


def test_place_layer_is_the_closest_spacing_that_keeps_order():
    # feasible desires are kept exactly
    assert rulegraph.place_layer([0.0, 5.0], [1.0, 1.0], 0.5) == [0.0, 5.0]
    # two boxes wanting the same spot split symmetrically around it, exactly gap apart
    x = rulegraph.place_layer([2.0, 2.0], [1.0, 3.0], 0.5)
    assert x[1] - x[0] == pytest.approx((1.0 + 3.0) / 2 + 0.5)
    assert (x[0] + x[1]) / 2 == pytest.approx(2.0)
    assert rulegraph._isotonic([3.0, 1.0, 2.0, 5.0]) == [2.0, 2.0, 2.0, 5.0]


def test_layout_keeps_edges_downward_and_boxes_apart():
    g = rulegraph.parse_rulegraph(DOT)
    xy, width, chains = rulegraph.layout(g, gap=0.2)
    for (a, b), chain in chains.items():
        ys = [xy[v][1] for v in chain]
        assert all(y1 == y0 - 1 for y0, y1 in zip(ys, ys[1:])), (a, b)  # one layer per step
    # the long edge simulate -> all passes through one dummy point per skipped layer
    assert len(chains[("simulate", "all")]) == 3  # layers 1 -> 3: a dummy on layer 2
    rows: dict[float, list] = {}
    for v, (x, y) in xy.items():
        rows.setdefault(y, []).append((x - width[v] / 2, x + width[v] / 2))
    for boxes in rows.values():
        boxes.sort()
        assert all(r0 + 0.2 <= l1 + 1e-9 for (_, r0), (l1, _) in zip(boxes, boxes[1:]))


def test_main_draws_a_png_sized_to_the_layout(tmp_path):
    dot = tmp_path / "g.dot"
    dot.write_text(DOT)
    png = tmp_path / "g.png"
    assert rulegraph.main([str(png), str(dot)]) == 0
    img = mpimg.imread(png)
    xy, _, _ = rulegraph.layout(rulegraph.parse_rulegraph(DOT))
    xs = [p[0] for p in xy.values()]
    assert img.shape[0] == int((3 + 1.2) * 110)  # four layers: 3 inches + margins, at 110 dpi
    assert img.shape[1] == int((max(xs) - min(xs) + 3.0) * 110)
    assert (img[..., :3] < 0.5).any()  # text and boxes drawn on the white background
    assert rulegraph.main([]) == 2
