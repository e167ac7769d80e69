"""neuronsmae-plot reads what the real records writer wrote and draws a PNG."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from neuronsmae.trainers.run import plot as P
from neuronsmae.trainers.run.config import TrainConfig
from neuronsmae.trainers.run.records import Recorder

pytest.importorskip("matplotlib")


def make_run(root: Path, seed: int, evals: int = 3, every: int = 100) -> Path:
    """A run directory written the way training writes one: config.json, then rows."""
    cfg = TrainConfig(alg="vdn", level="easy", seed=seed, out=str(root / f"vdn_s{seed}"))
    run = cfg.run_dir
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2))
    rec = Recorder(run, total_episodes=evals * every, done_episodes=0, progress=False)
    rng = np.random.default_rng(seed)
    for ep in range(10, evals * every + 1, 10):
        win = min(1.0, ep / (evals * every) + 0.1 * rng.random())
        rec.train({"episodes": ep, "env_steps": ep * 45, "updates": ep, "wall_seconds": ep / 10,
                   "epsilon": 0.1, "train_win_rate": win, "train_return": 20 * win - 10,
                   "loss": None, "q_taken": 0.0, "grad_norm": 1.0, "env_steps_per_s": 400.0,
                   "restarts": 0})  # fmt: skip
        if ep % every == 0:
            rec.eval({"episodes": ep, "env_steps": ep * 45 + seed, "updates": ep,
                      "wall_seconds": ep / 10, "win_rate": win, "draw_rate": 0.0,
                      "loss_rate": 1 - win, "mean_return": 20 * win - 10,
                      "eval_episodes": 20})  # fmt: skip
    final = {"episodes": evals * every, "env_steps": evals * every * 45 + seed, "updates": 0,
             "wall_seconds": 0.0, "win_rate": 0.0, "draw_rate": 0.0, "loss_rate": 1.0,
             "mean_return": -10.0, "eval_episodes": 20, "split": "test"}  # fmt: skip
    rec.eval(final)  # end-of-run test rows are not points of the curve
    rec.close()
    return run


def test_plot_writes_a_png_from_real_run_directories(tmp_path: Path) -> None:
    runs = [make_run(tmp_path, seed) for seed in (1, 2)]
    out = tmp_path / "curves.png"
    assert P.main([*map(str, runs), "--out", str(out)]) == 0
    with Image.open(out) as im:
        assert im.format == "PNG" and im.size[0] > 600 and im.size[1] > 300
    by_run = tmp_path / "by_run.png"  # a parent directory stands for the runs inside it
    assert P.main([str(tmp_path), "--by-run", "--source", "eval", "--out", str(by_run)]) == 0
    assert by_run.stat().st_size > 0


def test_runs_are_read_and_averaged_on_their_shared_episodes(tmp_path: Path) -> None:
    a, b = (P.load_run(make_run(tmp_path, s)) for s in (1, 2))
    assert (a.alg, a.level, a.seed) == ("vdn", "easy", 1)
    assert a.eval["episodes"].tolist() == [100, 200, 300]
    assert np.isnan(a.train["loss"]).all()  # blank cells read as NaN
    curves = [(r.eval["episodes"], r.eval["env_steps"], r.eval["win_rate"]) for r in (a, b)]
    x, mean, lo, hi = P.mean_and_spread(curves, exact=True)
    np.testing.assert_allclose(x, [100 * 45 + 1.5, 200 * 45 + 1.5, 300 * 45 + 1.5])
    both = np.stack([a.eval["win_rate"], b.eval["win_rate"]])
    np.testing.assert_allclose(mean, both.mean(0))
    np.testing.assert_allclose(lo, both.min(0))
    np.testing.assert_allclose(hi, both.max(0))
    # A shorter run limits the mean to the range every run reached.
    short = (curves[1][0][:2], curves[1][1][:2], curves[1][2][:2])
    x, *_ = P.mean_and_spread([curves[0], short], exact=True)
    assert len(x) == 2


def test_paper_numbers_and_bad_paths(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert P.PAPER_WIN_RATE["hard"] == {"iql": 0.23, "vdn": 0.41, "qmix": 0.34}
    assert P.main([str(tmp_path / "nowhere"), "--out", str(tmp_path / "x.png")]) == 2
    assert "not a run directory" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "config.json").write_text(json.dumps({"alg": "vdn", "level": "easy"}))
    assert P.main([str(empty), "--out", str(tmp_path / "x.png")]) == 2
    assert "nothing to plot" in capsys.readouterr().err
    # a PNG written under another name, and a directory, were taken as --out
    (tmp_path / "dir.png").mkdir()
    for out in (tmp_path / "curves.txt", tmp_path / "dir.png"):
        with pytest.raises(SystemExit) as exc:
            P.main([str(empty), "--out", str(out)])
        assert exc.value.code == 2
        assert f"--out must name a .png file, got {str(out)!r}" in capsys.readouterr().err


def test_paper_labels_close_together_do_not_overlap() -> None:
    from matplotlib.figure import Figure

    ax = Figure().subplots()
    P._paper_lines(ax, {("vdn", "easy"), ("qmix", "easy"), ("iql", "easy")})
    offsets = {t.get_text().split()[1]: t.xyann[1] for t in ax.texts}
    # 0.93 and 0.89 are closer than a label is tall: the lower one goes under its line.
    assert offsets == {"VDN": 3, "QMIX": -9, "IQL": 3}
    assert sorted(line.get_ydata()[0] for line in ax.lines) == [0.75, 0.89, 0.93]


@pytest.mark.parametrize(
    ("defect", "said"),
    [
        ("config.json a list", "config.json is not a run's configuration: a JSON list"),
        ("config.json not UTF-8", "config.json is unreadable: 'utf-8' codec can't decode"),
        ("train.csv not UTF-8", "train.csv is not a records CSV"),
        ("train.csv of other columns", "train.csv lacks the column(s) ['episodes', 'env_steps'"),
        ("eval.csv header of other columns", "eval.csv lacks the column(s) ['win_rate'"),
    ],
)
def test_a_malformed_run_is_refused_naming_its_file(
    defect: str, said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """AttributeError and UnicodeDecodeError tracebacks, or 'no rows ... yet' for a file of
    the wrong columns."""
    run = make_run(tmp_path, 1)
    if defect == "config.json a list":
        (run / "config.json").write_text("[1, 2]")
    elif defect == "config.json not UTF-8":
        (run / "config.json").write_bytes(b'{"alg": "\xff"}')
    elif defect == "train.csv not UTF-8":
        (run / "train.csv").write_bytes(b"episodes,env_steps\n\xff,1\n")
    elif defect == "train.csv of other columns":
        (run / "train.csv").write_text("a,b\n1,2\n")
    else:
        (run / "eval.csv").write_text("episodes,env_steps,mean_return\n")
    out = tmp_path / "x.png"
    assert P.main([str(run), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{run}/{said}" in err
    assert not out.exists()


def test_a_run_named_twice_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``neuronsmae-plot r r`` drew one run as two ("2 runs"), skewing mean and spread."""
    run = make_run(tmp_path / "runs", 1)
    make_run(tmp_path / "runs", 2)
    out = tmp_path / "x.png"
    for argv in ([str(run), str(run)], [str(run), str(tmp_path / "runs")],
                 [str(run), str(tmp_path / "runs" / ".." / "runs" / run.name)]):  # fmt: skip
        assert P.main([*argv, "--out", str(out)]) == 2
        assert f"run {run} is named twice" in capsys.readouterr().err
    assert not out.exists()
    assert P.main([str(tmp_path / "runs"), "--out", str(out)]) == 0
    assert "(2 runs)" in capsys.readouterr().out


def test_an_out_whose_folder_is_a_file_is_refused_naming_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It printed "[Errno 17] File exists" without saying which path."""
    run = make_run(tmp_path, 1)
    (tmp_path / "keep.gif").write_bytes(b"GIF89a")
    out = tmp_path / "keep.gif" / "x.png"
    with pytest.raises(SystemExit) as exc:
        P.main([str(run), "--out", str(out)])
    assert exc.value.code == 2
    assert f"--out {out}: {tmp_path / 'keep.gif'} is a file, not a folder" in (
        capsys.readouterr().err
    )
    assert (tmp_path / "keep.gif").read_bytes() == b"GIF89a"
    shown = subprocess.run([sys.executable, "-m", "neuronsmae.trainers.run.plot", "--help"],
                           capture_output=True, text=True, check=True, timeout=120)  # fmt: skip
    assert "replaced if it exists" in " ".join(shown.stdout.split())
