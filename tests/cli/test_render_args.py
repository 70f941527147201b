"""The render flags of ``clipvol render``, ``view``, ``slice`` and ``report`` come from one table
(:mod:`clipvol.tools.render_args`): typed flags set the RenderParams fields they name, and a
command given no flag draws with RenderParams' own defaults.

References: the defaults of the :class:`~clipvol.scene.params.RenderParams` dataclass (read from
``dataclasses.fields``, not through the flag table), and literal values typed on the command line.
"""

from __future__ import annotations

import dataclasses

import pytest

from clipvol.errors import ParameterError
from clipvol.scene.params import RenderParams
from clipvol.tools.cli import build_parser, main
from clipvol.tools.render_args import FLAGS, render_params_from_args

#: --texture-budget's default is 256MB, decimal megabytes (RenderParams' is 256 MiB): documented at its flag
BUDGET = {"texture_budget": 256_000_000}
#: each command's minimal command line, the fields it sets itself, and where its defaults are not
#: RenderParams' own, on purpose
COMMANDS = {
    "render": (["render", "procedural:fractal", "-o", "a.png"], {}, BUDGET),
    "view": (["view", "procedural:fractal"], {}, {**BUDGET, "jitter": True}),  # jitter unless --no-jitter
    "slice": (["slice", "procedural:fractal"], {"policy": "plane"}, BUDGET),
    "report": (["report", "procedural:fractal", "--out", "r"], {}, {}),
}


def _field_defaults() -> dict:
    return {f.name: f.default for f in dataclasses.fields(RenderParams)
            if f.default is not dataclasses.MISSING}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_no_flag_means_the_field_defaults(command):
    argv, fixed, own = COMMANDS[command]
    args = build_parser().parse_args(argv)
    got = render_params_from_args(args, **fixed)
    want = RenderParams(**{**_field_defaults(), **fixed, **own})
    for f in dataclasses.fields(RenderParams):
        assert getattr(got, f.name) == getattr(want, f.name), (command, f.name)


def test_render_flags_set_their_fields():
    args = build_parser().parse_args(
        ["render", "procedural:fractal", "-o", "a.png", "--mode", "mip", "--policy", "fixed", "--level", "2", "--lod-threshold", "3",
         "--distance-factor", "4", "--fov-fraction", "0.25", "--max-texels-drawn", "1000", "--block-budget", "7",
         "--no-visibility", "--step", "0.75", "--background", "0,0.5,1,1", "--shading", "--light", "0.1,0.2,0.4,8",
         "--texture-budget", "1MiB", "--texels-per-frame", "4096"])
    p = render_params_from_args(args)
    assert (p.mode, p.policy, p.level, p.lod_threshold, p.distance_factor, p.fov_fraction) == \
        ("mip", "fixed", 2, 3.0, 4.0, 0.25)
    assert (p.max_texels_drawn, p.block_budget, p.visibility, p.step, p.background) == \
        (1000, 7, False, 0.75, (0.0, 0.5, 1.0, 1.0))
    assert (p.shading, p.ambient, p.diffuse, p.specular, p.shininess) == (True, 0.1, 0.2, 0.4, 8.0)
    assert (p.texture_budget, p.texels_per_frame) == (1 << 20, 4096)


def test_view_flags_set_their_fields():
    args = build_parser().parse_args(["view", "procedural:fractal", "--policy", "roaming", "--no-jitter",
                                      "--render-path", "bricks", "--shading"])
    p = render_params_from_args(args)
    assert (p.policy, p.jitter, p.path, p.shading) == ("roaming", False, "bricks", True)


def test_slice_keeps_its_plane_policy():
    args = build_parser().parse_args(["slice", "procedural:fractal", "--level", "1", "--distance-factor", "2",
                                      "--poi", "1,2,3"])
    p = render_params_from_args(args, policy="plane", focus=args.poi)
    assert (p.policy, p.level, p.distance_factor, p.focus) == ("plane", 1, 2.0, (1.0, 2.0, 3.0))


def test_every_flag_names_real_fields_with_help():
    names = set(RenderParams.names())
    for handle, flag in FLAGS.items():
        assert handle == (flag.fields[0] if len(flag.fields) == 1 else flag.dest), handle
        assert set(flag.fields) <= names, handle
        assert flag.flag.startswith("--")
        assert flag.help or RenderParams.help(flag.fields[0]), handle


@pytest.mark.parametrize("argv", [
    ["render", "procedural:fractal", "--selection", "fixed"],  # --policy is the one name
    ["view", "procedural:fractal", "--selection", "fixed"],
    ["render", "procedural:fractal", "--policy", "multiresolution"],  # projected-size is the one name
])
def test_old_names_are_refused(argv, capsys):
    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(argv)
    assert e.value.code == 2
    assert "Traceback" not in capsys.readouterr().err


def test_the_window_refuses_a_policy_it_cannot_start_with(capsys):
    """``view --policy`` offers every policy (``--offscreen`` draws each); the window starts with one
    of the four it can cycle and refuses the others before it opens, naming the flag."""
    assert main(["view", "procedural:fractal?size=16", "--policy", "distance"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clipvol view: error: --policy:") and "distance" in err[0], err


def test_a_short_light_is_one_error_line(tmp_path, capsys):
    args = build_parser().parse_args(["render", "procedural:fractal", "-o", "a.png", "--light", "0.1,0.2"])
    with pytest.raises(ParameterError, match="--light"):
        render_params_from_args(args)
    assert main(["render", "procedural:fractal?size=16", "--out", str(tmp_path / "a.png"), "--light", "1,2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--light" in err[0] and "Traceback" not in err[0]
