from click.testing import CliRunner
from rlpgo_cli.generate import main

from rlpgo_gtsam import chi2, read_g2o


def test_generate_writes_graph_and_ground_truth(tmp_path):
    out, truth = tmp_path / "g.g2o", tmp_path / "gt.g2o"
    result = CliRunner().invoke(main, ["--n", "300", "--sigma-r", "0.3", "--sigma-t", "0.05",
                                       "--d", "3", "--lc", "0.5", "--seed", "1",
                                       "-o", str(out), "--ground-truth", str(truth)])
    assert result.exit_code == 0, result.output
    graph, initial = read_g2o(out)
    _, ground_truth = read_g2o(truth)
    assert (initial.size(), graph.size()) == (300, 430)
    assert chi2(graph, ground_truth) < 1e-12 < 1e3 < chi2(graph, initial)


def test_generate_is_seeded(tmp_path):
    texts = []
    for name, seed in [("a", "4"), ("b", "4"), ("c", "5")]:
        path = tmp_path / f"{name}.g2o"
        CliRunner().invoke(main, ["--n", "40", "--seed", seed, "--noisy-measurements",
                                  "-o", str(path)])
        texts.append(path.read_text())
    assert texts[0] == texts[1] != texts[2]

