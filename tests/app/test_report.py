"""The error-against-run-time report on a tiny volume: files, columns, error falling with the threshold,
warm interleaved timing (two settings that draw the same cut take the same time) and the one-line answer."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from PIL import Image

pytest.importorskip("moderngl")


#: the report's adaptive-sampling sweep here: the first default at level 0 and the first at level 1
#: (every default setting is timed in interleaved rounds; two of them exercise both kinds of row)
def _refines():
    from clipvol.app.report import DEFAULT_REFINES

    return (DEFAULT_REFINES[0], next(r for r in DEFAULT_REFINES if len(r) == 3 and r[2] == 1))


REFINES = _refines()


@pytest.fixture(scope="module")
def report(tmp_path_factory, ctx):
    from clipvol.loaders.procedural import ProceduralLoader
    from clipvol.app.report import run_report

    out = tmp_path_factory.mktemp("report")
    loader = ProceduralLoader("procedural:fractal?size=32&seed=1", brick=8)
    res = run_report(loader, out, views=2, size=(48, 48), thresholds=(0.5, 2.0, 8.0), memory_budgets=(),
                     texture_budgets=("40kB",), refines=REFINES, tf="grey", ctx=ctx, max_frames=3, rounds=2)
    return res, loader


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_files_and_columns(report):
    from clipvol.app.report import REPORT_COLUMNS

    res, _ = report
    for p in [res.csv, res.timing_csv, res.markdown, *res.plots, *res.images]:
        assert p.is_file() and p.stat().st_size > 0, p
    assert {p.name for p in res.plots} == {"error_vs_time.png", "error_vs_bytes.png", "lod_budget.png"}
    with open(res.csv, newline="") as fh:
        header = next(csv.reader(fh))
    assert tuple(header) == REPORT_COLUMNS
    rows = _rows(res.csv)
    assert {r["sweep"] for r in rows} == {"fixed", "lod_threshold", "texture_budget", "refine"}
    assert {r["kind"] for r in rows} == {"converged", "as-it-comes"}
    md = res.markdown.read_text()
    assert "error_vs_time.png" in md
    # papers cited by authors, title and year in a References section, never by a file number
    import re

    assert "## References" in md and "LaMar, B. Hamann and K. I. Joy" in md and "1999" in md
    assert not re.search(r"\bseed", md, re.I)


def test_converged_rows_are_consistent(report):
    res, loader = report
    pyr = loader.pyramid
    for r in _rows(res.csv):
        if r["kind"] != "converged":
            continue
        if r["sweep"] != "texture_budget":  # a tiny texture budget may not hold the wanted bricks
            assert r["converged"] == "1", r
        assert int(r["bytes_needed"]) == int(r["bricks_drawn"]) * pyr.brick_nbytes
        assert float(r["frame_s"]) > 0 and float(r["converge_s"]) >= 0
        if r["sweep"] == "fixed":
            # the full-resolution frame is level 0 everywhere: every level-0 brick in view
            assert int(r["bricks_drawn"]) == pyr.num_bricks(0)


def test_the_baseline_is_the_converged_picture(report):
    """Errors are against the converged picture (level 0, step 0.25, 2x2 rays per pixel), not the
    full-resolution frame: the two saved images differ, the full-resolution frame's own error is
    in the rows (recomputed from the PNGs with numpy), and report.md names the baseline and shows
    the full-resolution frame's error beside the settings."""
    res, _ = report
    rows = [r for r in _rows(res.csv) if r["kind"] == "converged" and r["sweep"] == "fixed"]
    for v in ("0", "1"):
        ref = np.asarray(Image.open(res.out_dir / f"reference_view{v}.png"), dtype=np.float64)
        full = np.asarray(Image.open(res.out_dir / f"full_resolution_view{v}.png"), dtype=np.float64)
        a = full[..., :3] * full[..., 3:4] / 255.0
        b = ref[..., :3] * ref[..., 3:4] / 255.0
        rmse = np.sqrt(np.mean((a - b) ** 2))
        assert rmse > 0.5  # a fine step and four rays per pixel draw another picture
        r = next(r for r in rows if r["view"] == v)
        assert float(r["rmse"]) == pytest.approx(rmse, abs=0.6)
    md = res.markdown.read_text()
    assert "converged picture" in md and "level 0 at step 0.25 voxel, 2x2 rays per pixel" in md
    assert "| full res % |" in md and "the full-resolution frame itself:" in res.headline


def test_error_falls_as_threshold_falls(report):
    res, _ = report
    conv = [r for r in _rows(res.csv) if r["kind"] == "converged" and r["sweep"] == "lod_threshold"]
    by_t = {}
    for r in conv:
        by_t.setdefault(float(r["lod_threshold"]), []).append(float(r["rmse"]))
    ts = sorted(by_t)
    err = [np.mean(by_t[t]) for t in ts]
    bricks = {}
    for r in conv:
        bricks.setdefault(float(r["lod_threshold"]), []).append(int(r["bricks_drawn"]))
    # finer threshold: never fewer bricks, never more error; the extremes differ
    assert all(np.mean(bricks[a]) >= np.mean(bricks[b]) for a, b in zip(ts, ts[1:]))
    assert all(e1 <= e2 + 1e-9 for e1, e2 in zip(err, err[1:])), err
    assert err[0] < err[-1]


def test_csv_errors_match_the_saved_images(report):
    """Recompute RMSE from the written PNGs with numpy (composited over black, 8-bit RGB)."""
    res, _ = report
    ref = np.asarray(Image.open(res.out_dir / "reference_view0.png"), dtype=np.float64)
    rows = {float(r["lod_threshold"]): r for r in _rows(res.csv)
            if r["kind"] == "converged" and r["sweep"] == "lod_threshold" and r["view"] == "0"}
    for t, r in rows.items():
        img = np.asarray(Image.open(res.out_dir / f"view0_lod{t:g}.png"), dtype=np.float64)
        a = img[..., :3] * img[..., 3:4] / 255.0
        b = ref[..., :3] * ref[..., 3:4] / 255.0
        rmse = np.sqrt(np.mean((a - b) ** 2))
        assert float(r["rmse"]) == pytest.approx(rmse, abs=0.6), (t, r["rmse"], rmse)


def _paired(raw, ref="fixed L0"):
    """From the raw rows alone: per (block, setting, view), the frame times and the reference-over-
    setting ratio of every pair."""
    times, ratios, pairs = {}, {}, {}
    for r in raw:
        times.setdefault((r["block"], r["setting"], r["view"]), []).append(float(r["frame_s"]))
        pairs.setdefault((r["block"], r["pair"]), []).append(r)
    for (block, _), two in pairs.items():
        assert len(two) == 2 and {t["round"] for t in two} == {two[0]["round"]} and two[0]["view"] == two[1]["view"]
        (f,), (o,) = [t for t in two if t["setting"] == ref], [t for t in two if t["setting"] != ref]
        ratios.setdefault((block, o["setting"], o["view"]), []).append(float(f["frame_s"]) / float(o["frame_s"]))
    return times, ratios


def test_frame_times_and_speedups_come_from_the_paired_rounds(report):
    """Every converged row's frame time is the median of its own warm rounds in ``timing.csv``, and
    its speed-up the median over its pairs (each a reference frame drawn next to one of the
    setting's) of the reference's time over the setting's."""
    res, _ = report
    times, ratios = _paired(_rows(res.timing_csv))
    settings = {s for _, s, _ in ratios}
    assert all(len(t) == 2 for k, t in ratios.items())  # rounds=2: one pair per round and view
    block_of = {setting: block for block, setting, _ in ratios}
    assert block_of["lod=2"] == "0" and block_of["tex=40.0 kB"] != "0"
    conv = [r for r in _rows(res.csv) if r["kind"] == "converged"]
    assert {r["setting"] for r in conv} - settings == {"fixed L0"}
    for r in conv:
        b = block_of.get(r["setting"], "0")
        med = np.median(times[(b, r["setting"], r["view"])])
        assert float(r["frame_s"]) == pytest.approx(med, abs=2e-6)
        assert float(r["ref_frame_s"]) == pytest.approx(np.median(times[(b, "fixed L0", r["view"])]), abs=2e-6)
        want = 1.0 if r["setting"] == "fixed L0" else np.median(ratios[(b, r["setting"], r["view"])])
        assert float(r["speedup"]) == pytest.approx(want, rel=1e-3)
        assert float(r["frame_min_s"]) <= float(r["frame_s"]) <= float(r["frame_max_s"])
    # the block-budget policies are paired with the reference in its block too
    lod = _rows(res.out_dir / "lod_budget.csv")
    assert lod and all(("0", f"{r['policy']} b={r['budget']}", r["view"]) in ratios for r in lod)
    assert res.headline.startswith("at <= 5 %") and res.headline[1:] in res.markdown.read_text()


@pytest.mark.slow  # 21 interleaved rounds (18 s on CI's 2 cores): the timing method, not a feature
def test_two_settings_drawing_the_same_cut_take_the_same_time(tmp_path, ctx):
    """Fixed level 0 and a threshold so fine that it picks every level-0 brick draw the same bricks
    the same way: warm, interleaved and paired, the report gives them the same time within noise,
    so a bias towards whichever setting is timed first (a cold first frame) shows here. A test of
    the timing method, not a speed target."""
    from clipvol.loaders.procedural import ProceduralLoader
    from clipvol.app.report import run_report, summarise

    # each timed frame is the third at its view (report_measure.SETTLING_FRAMES): the fixed level's
    # cut is drawn again, the projected-size cut kept for the camera that did not move
    # (clipvol.render.frame_loop, "Coherence"): neither selects anew, so what is compared is the
    # timing method alone
    loader = ProceduralLoader("procedural:fractal?size=32&seed=3", brick=8)
    res = run_report(loader, tmp_path, views=2, size=(32, 32), thresholds=(0.01,), memory_budgets=(),
                     texture_budgets=(), block_budgets=(), tf="grey", ctx=ctx, max_frames=2, rounds=21,
                     plots=False)
    conv = {(r["setting"], r["view"]): r for r in _rows(res.csv) if r["kind"] == "converged"}
    for v in ("0", "1"):  # the same cut: every level-0 brick, identical images
        assert int(conv[("lod=0.01", v)]["bricks_drawn"]) == int(conv[("fixed L0", v)]["bricks_drawn"]) \
            == loader.pyramid.num_bricks(0)
        # identical images: the same error against the converged picture
        assert float(conv[("lod=0.01", v)]["pct_de6"]) == float(conv[("fixed L0", v)]["pct_de6"])
    # recomputed from the raw rounds: the median of the paired ratios (the load of a shared machine
    # drifts over seconds; the two frames of a pair are drawn one right after the other)
    _, ratios = _paired(_rows(res.timing_csv))
    paired = np.median(ratios[("0", "lod=0.01", "0")] + ratios[("0", "lod=0.01", "1")])
    assert 0.8 <= paired <= 1.25, paired
    s = {x["setting"]: x for x in summarise(res.rows)}
    assert 0.8 <= s["lod=0.01"]["speedup"] <= 1.25, s["lod=0.01"]


def _summary(setting, speedup, pct, sweep="lod_threshold"):
    return dict(sweep=sweep, setting=setting, speedup=speedup, pct_de6_max=pct, frame_s=0.01 / speedup,
                ref_frame_s=0.01)


def test_headline_names_the_fastest_setting_within_the_target():
    from clipvol.app.report import headline

    ref = _summary("fixed L0", 1.0, 0.0, "fixed")
    summ = [ref, _summary("lod=1", 1.1, 0.0), _summary("lod=4", 3.0, 4.9), _summary("lod=16", 9.0, 12.0)]
    line = headline(summ, rounds=5, views=3)
    assert "3.0x faster" in line and "setting lod=4" in line and "5 %" in line and "5 interleaved rounds" in line
    assert "10.0 ms for fixed L0" in line
    line = headline([ref, _summary("lod=16", 9.0, 12.0)], rounds=5, views=3)
    assert line.startswith("no setting reaches") and "lod=16" in line
    line = headline([ref, _summary("lod=1", 0.8, 0.0)], rounds=5, views=3)
    assert "no setting is faster" in line and "1.25x its time" in line


@pytest.mark.parametrize("bad", ["0", "-2", "five"])
def test_cli_rounds_must_be_a_positive_integer(tmp_path, capsys, bad):
    """``--rounds`` is checked before any data is opened: one line naming it, exit 2."""
    from clipvol.tools.cli import main

    with pytest.raises(SystemExit) as e:
        main(["report", str(tmp_path / "absent.zarr"), "--out", str(tmp_path / "rep"), "--rounds", bad])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--rounds" in err and "expected an integer >= 1" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rep").exists()


def test_run_report_rejects_bad_rounds(tmp_path):
    from clipvol.app.report import run_report
    from clipvol.errors import ParameterError

    with pytest.raises(ParameterError, match="rounds"):
        run_report("procedural:fractal?size=16", tmp_path, rounds=0)


@pytest.mark.slow
def test_error_budgets_are_settings_of_the_report(tmp_path, ctx):
    """The image policy's --max-error budgets are measured like every other setting: converged frames
    compared with the full-resolution reference, warm timed frames, a row in the summary."""
    from clipvol.app.report import run_report, summarise
    from clipvol.bricking.generators import ct_head
    from clipvol.bricking.pipeline import brick_volume

    store = tmp_path / "head.zarr"
    brick_volume(ct_head((32, 32, 32), seed=1), store, brick=8, progress=False)
    res = run_report(store, tmp_path / "r", views=1, size=(48, 48), thresholds=(4.0,), memory_budgets=(),
                     texture_budgets=(), block_budgets=(), max_errors=("20%", 0.02), tf="bone", ctx=ctx,
                     max_frames=2, rounds=1, plots=False)
    assert not res.skipped, res.skipped
    conv = {r["setting"]: r for r in _rows(res.csv) if r["kind"] == "converged"}
    assert conv["max-error=20%"]["selection"] == "image" and conv["max-error=2%"]["selection"] == "image"
    assert int(conv["max-error=2%"]["bricks_drawn"]) >= int(conv["max-error=20%"]["bricks_drawn"])
    s = {x["setting"]: x for x in summarise(res.rows)}
    assert s["max-error=2%"]["sweep"] == "max_error" and s["max-error=2%"]["speedup"] > 0
    # the policy's own prediction is printed beside the measurement: within the budget it stopped at
    # (or the finest cut it could reach), none for settings whose policy predicts nothing
    for name, budget in (("max-error=20%", 20.0), ("max-error=2%", 2.0)):
        pred = float(conv[name]["predicted_pct_de6"])
        assert 0.0 <= pred <= budget, (name, pred)
    assert conv["lod=4"]["predicted_pct_de6"] == "" and conv["fixed L0"]["predicted_pct_de6"] == ""
    md = res.markdown.read_text()
    assert "## The image policy's estimate against the measurement" in md
    row = next(line for line in md.splitlines() if line.startswith("| max-error=20% |"))
    assert f"{float(conv['max-error=20%']['predicted_pct_de6']):.2f} / {float(conv['max-error=20%']['pct_de6']):.2f}" in row


def test_report_rejects_a_bad_error_budget(tmp_path):
    from clipvol.app.report import run_report
    from clipvol.errors import ParameterError

    with pytest.raises(ParameterError, match="max_error"):
        run_report("procedural:fractal?size=16", tmp_path, max_errors=("5",))


def test_cli_max_error_is_checked_before_anything_is_drawn(tmp_path, capsys):
    from clipvol.tools.cli import main

    rc = main(["report", "procedural:fractal?size=16", "--brick", "8", "--out", str(tmp_path / "rep"),
               "--max-errors", "5%,150%"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "max_error" in err and "'150%'" in err
    assert not (tmp_path / "rep" / "report.csv").exists()


def test_adaptive_sampling_settings_are_rows_of_the_report(report):
    """The sweep "refine": level 0 (and level 1, a coarser level classified by its distribution) at
    a coarser step with adaptive image sampling, measured like every setting (converged frames
    against the reference, warm timing); the default sweep holds both kinds."""
    from clipvol.app.report import DEFAULT_REFINES, summarise

    res, _ = report
    conv = [r for r in _rows(res.csv) if r["kind"] == "converged" and r["sweep"] == "refine"]
    want = {(f"step={st:g} refine={tol:g}" if not lv else f"L{lv[0]} step={st:g} refine={tol:g}",
             str(lv[0] if lv else 0)) for st, tol, *lv in REFINES}
    assert any(len(d) == 3 and d[2] == 1 for d in DEFAULT_REFINES)  # a coarse level among them
    assert any(len(d) == 2 for d in DEFAULT_REFINES)
    assert {(r["setting"], r["level"]) for r in conv} == want
    assert all(r["selection"] == "fixed" for r in conv)
    n_bricks = {(r["setting"], r["view"]): int(r["bricks_drawn"]) for r in conv}
    assert all(n_bricks[(s, v)] < n_bricks[(next(iter(x for x, lv in want if lv == "0")), v)]
               for (s, v) in n_bricks if s.startswith("L1 "))  # level 1 draws fewer bricks
    s = {x["setting"]: x for x in summarise(res.rows)}
    assert all(s[r["setting"]]["speedup"] > 0 for r in conv)


def test_cli_refine_is_checked_before_anything_is_drawn(tmp_path, capsys):
    from clipvol.tools.cli import main

    for bad, name in (("2.5", "--refine"), ("2:1.5", "refine_tolerance"), ("1:0.2:x", "--refine"),
                      ("1:0.2:-1", "level")):
        rc = main(["report", "procedural:fractal?size=16", "--brick", "8", "--out", str(tmp_path / "rep"),
                   "--refine", bad])
        assert rc == 2
        assert name in capsys.readouterr().err
        assert not (tmp_path / "rep" / "report.csv").exists()


def test_cli_budget_lists_are_checked_while_parsing(tmp_path, capsys):
    from clipvol.tools.cli import main

    with pytest.raises(SystemExit) as e:
        main(["report", "procedural:fractal?size=16", "--brick", "8", "--out", str(tmp_path / "rep"),
              "--memory-budgets", "64MB,12XB"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--memory-budgets" in err and "'12XB'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rep").exists()


def test_report_frames_what_the_transfer_function_shows(tmp_path, ctx):
    """``frame="visible"`` (the default): the orbit's views look at the voxels with opacity
    (:func:`visible_box`, itself tested against the table's lookup) from where they fill them, so the
    anatomy covers more of each image than with ``frame="volume"``."""
    from clipvol.app.report import run_report
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.scene.framing import visible_box
    from clipvol.scene.transfer import TransferFunction

    vol = np.zeros((40, 40, 40), dtype=np.uint16)
    vol[22:34, 6:18, 9:21] = 900  # tissue in one corner of the air
    kw = dict(views=1, size=(48, 48), thresholds=(4.0,), memory_budgets=(), texture_budgets=(), block_budgets=(),
              max_errors=(), refines=(), tf=TransferFunction.preset("bone", value_range=(0.0, 1000.0)), ctx=ctx,
              max_frames=2, rounds=1, plots=False)
    covered = {}
    for frame in ("visible", "volume"):
        loader = NumpyLoader(vol, brick=16)
        res = run_report(loader, tmp_path / frame, frame=frame, **kw)
        if frame == "visible":
            want = visible_box(loader, kw["tf"])
            np.testing.assert_allclose(res.framed[0], want[0])
            np.testing.assert_allclose(res.framed[1], want[1])
            assert "framing the voxels the transfer function makes visible" in res.markdown.read_text()
        else:
            assert res.framed is None and "framing the whole volume" in res.markdown.read_text()
        ref = [p for p in res.images if "fixed" in p.name or "reference" in p.name][0]
        img = np.asarray(Image.open(ref).convert("RGB")).astype(int)
        covered[frame] = int((np.abs(img - img[0, 0]).sum(axis=2) > 30).sum())
    assert covered["visible"] > 2 * covered["volume"] > 0, covered


def test_report_rejects_an_unknown_frame(tmp_path):
    from clipvol.app.report import run_report
    from clipvol.errors import ParameterError

    with pytest.raises(ParameterError, match="frame"):
        run_report("procedural:fractal?size=16", tmp_path, frame="brain")


@pytest.mark.parametrize("flag,bad", [("--supersample", "0"), ("--supersample", "two"), ("--converged-step", "-1")])
def test_cli_converged_picture_flags_are_checked(tmp_path, capsys, flag, bad):
    """``--supersample`` and ``--converged-step`` are checked before any data is opened: one line
    naming the flag, exit 2, nothing written."""
    from clipvol.tools.cli import main

    with pytest.raises(SystemExit) as e:
        main(["report", str(tmp_path / "absent.zarr"), "--out", str(tmp_path / "rep"), flag, bad])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert flag in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rep").exists()


def test_run_report_rejects_a_bad_supersample(tmp_path):
    from clipvol.app.report import run_report
    from clipvol.errors import ParameterError
    from clipvol.loaders.procedural import ProceduralLoader

    with pytest.raises(ParameterError, match="supersample"):
        run_report(ProceduralLoader("procedural:fractal?size=16&seed=1", brick=8), tmp_path / "rep", supersample=0)
    assert not (tmp_path / "rep").exists()


@pytest.mark.parametrize("flag, want", [((), "distribution"), (("--classify", "mean"), "mean")])
def test_cli_classify_reaches_every_frame(tmp_path, ctx, monkeypatch, flag, want):
    """``clipvol report --classify mean`` classifies every frame it draws - the converged picture,
    the reference and each setting - by the mean (the default: by the distribution). Recorded from
    the render action's own parameters at each draw, not from what the command parsed."""
    import clipvol.app.report_measure as rm
    from clipvol.app.session import RenderSession
    from clipvol.bricking.generators import ct_head
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.tools.cli import main

    store = tmp_path / "head.zarr"
    brick_volume(ct_head((24, 24, 24), seed=1), store, brick=8, progress=False)
    seen = []
    real = RenderSession.render

    def render(self, *a, **k):
        seen.append(self.action.params.classify)
        return real(self, *a, **k)

    monkeypatch.setattr(RenderSession, "render", render)
    monkeypatch.setattr(rm, "create_context", lambda: ctx)  # the session's context, kept after the report
    monkeypatch.setattr(ctx, "release", lambda: None)
    rc = main(["report", str(store), "--out", str(tmp_path / "rep"), "--views", "1", "--size", "32x32",
               "--thresholds", "4", "--memory-budgets", "none", "--texture-budgets", "none", "--block-budgets",
               "none", "--max-errors", "none", "--refine", "none", "--rounds", "1", "--max-frames", "2",
               "--no-plots", "--tf", "bone", *flag])
    assert rc == 0
    assert len(seen) >= 4 and set(seen) == {want}, seen
    assert f"(`--classify {want}`)" in (tmp_path / "rep" / "report.md").read_text()  # the report says what it drew


def test_cli_rejects_an_unknown_classify(tmp_path, capsys):
    from clipvol.tools.cli import main

    with pytest.raises(SystemExit) as e:
        main(["report", "procedural:fractal?size=16", "--out", str(tmp_path / "rep"), "--classify", "median"])
    assert e.value.code == 2 and "--classify" in capsys.readouterr().err
    assert not (tmp_path / "rep").exists()


def test_budgets_that_hold_the_pyramid_hold_it_with_its_spread(tmp_path, ctx):
    """A store with consistent coarse levels keeps each coarse brick's spread beside it, and the GPU
    cache holds every level at two channels. The report's budgets that "hold everything" must hold
    that too: drawn from one session, going back and forth between full resolution and a coarse
    setting (what the report's interleaved timing does) uploads nothing after the first time round.
    With budgets sized for the means alone, every change evicted and uploaded again."""
    from clipvol.app.report_measure import _holding_budgets
    from clipvol.app.session import RenderSession, open_loader
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.scene.params import RenderParams
    from clipvol.scene.paths import make_path

    z, y, x = np.mgrid[:64, :64, :64] / 63.0 - 0.5
    ball = np.clip(1.0 - np.sqrt(x * x + y * y + z * z) / 0.5, 0.0, 1.0)
    np.save(tmp_path / "v.npy", (255 * ball * (0.6 + 0.4 * np.sin(40 * x) * np.cos(30 * y))).clip(0, 255).astype(np.uint8))
    brick_volume(tmp_path / "v.npy", tmp_path / "v.zarr", brick=8, progress=False)
    loader = open_loader(str(tmp_path / "v.zarr"))
    assert loader.spread_levels  # the store carries the spread (else this tests nothing)
    mem, tex = _holding_budgets(loader, 0)
    cams = list(make_path("orbit", loader.pyramid, 2, size=(64, 64)))
    fine = RenderParams(policy="fixed", level=0, texture_budget=tex, step=1.0)
    with RenderSession(loader, ctx, memory_budget=mem, params=fine, tf="grey") as sess:
        assert sess.clip_texture.spread_levels == loader.spread_levels  # the memory budget kept the spread
        uploads = []
        for rnd in range(3):
            for ch in (dict(policy="fixed", level=0), dict(policy="projected-size", lod_threshold=1.0),
                       dict(policy="projected-size", lod_threshold=4.0), dict(policy="image", block_budget=64)):
                sess.update(**ch)
                for cam, coi in cams:
                    sess.render(cam, coi, wait=True, timeout=60)
                    uploads.append((rnd, ch, sess.frame_stats.bytes_uploaded))
    assert any(up for rnd, _, up in uploads if rnd == 0)
    assert [u for u in uploads if u[0] > 0 and u[2]] == []


@pytest.mark.parametrize("settling", [None, 1])
def test_the_timed_frame_draws_a_kept_cut_not_its_build(ctx, monkeypatch, settling):
    """The report times the frames a user gets while holding a view. A projected-size cut is kept
    between frames, built from nothing in the frame after a new cut (clipvol.render.frame_loop,
    "Coherence"): a timed frame that is that build charges every projected-size setting a cost a
    user pays once per change (the demo's ``lod=1``, the very bricks of the full-resolution frame,
    measured 0.87-0.94x its speed so). Each timed frame here draws the kept cut: updated for the
    view, never built in it. ``settling=1`` is the method that timed the second frame: it must be
    caught."""
    from clipvol.app import report_measure as rm
    from clipvol.app.session import RenderSession
    from clipvol.loaders.procedural import ProceduralLoader
    from clipvol.scene.params import RenderParams
    from clipvol.scene.paths import make_path
    from clipvol.scene.selection.kept_cut import KeptCut

    if settling is not None:
        monkeypatch.setattr(rm, "SETTLING_FRAMES", settling)
    loader = ProceduralLoader("procedural:fractal?size=32&seed=3", brick=8)
    base = RenderParams(step=0.5, path="single-pass")  # the path that draws a kept cut
    fixed = rm._Setting("fixed", "fixed L0", 1.0, 1 << 26, 1 << 26, "fixed", 0)
    lod = rm._Setting("lod_threshold", "lod=2", 2.0, 1 << 26, 1 << 26)
    views = list(make_path("orbit", loader.pyramid, 2, size=(32, 32)))
    calls: list = []  # per KeptCut.update: whether it built the cut from nothing
    update = KeptCut.update

    def spy(self, camera, ordered=True):
        calls.append(self.drawn is None)
        return update(self, camera, ordered)

    monkeypatch.setattr(KeptCut, "update", spy)
    timed: list = []  # per timed frame of the projected-size setting: (built in it, drawn from a kept cut)
    warm = rm._warm_frame_s

    def timed_frame(sess, cam, coi, timeout):
        n = len(calls)
        dt = warm(sess, cam, coi, timeout)
        if sess.params.policy == "projected-size":
            fs = sess.frame_stats
            timed.append((any(calls[n:]), fs.updated or fs.replayed))
        return dt

    monkeypatch.setattr(rm, "_warm_frame_s", timed_frame)
    with RenderSession(loader, ctx, memory_budget="64MB", params=fixed.params(base), tf="grey") as sess:
        rm._time_block((sess, fixed), [(sess, lod)], views, 3, base, 30.0, 0, [])
    rounds = timed[len(views):]  # (the first ones: each view warmed once, before the rounds)
    assert len(rounds) == 3 * len(views)
    if settling is None:
        assert all(kept for _, kept in rounds), timed  # drawn from the kept cut ...
        assert not any(built for built, _ in rounds), timed  # ... never built in a timed frame
    else:
        assert any(built for built, _ in rounds), timed
