"""``clipvol.choices`` names what the library accepts: each tuple equals the registry or table it
stands for, read from the library itself (the policies registered at import, the view and opacity
tables, the camera paths, the transfer-function presets that build), and the module imports nothing.

Why: the command line offers these names without importing numpy; a policy, view, path or preset
added to the library but not here would be refused by ``--help``'s parser, one here but not in the
library would be offered and then refused.
"""

from __future__ import annotations

import ast
from dataclasses import fields
from pathlib import Path

import pytest

from clipvol import choices


def test_the_module_imports_nothing():
    tree = ast.parse(Path(choices.__file__).read_text())
    imports = [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]
    assert all(isinstance(n, ast.ImportFrom) and n.module == "__future__" for n in imports), imports


def test_policies_are_the_registered_ones():
    from clipvol.scene.policy_registry import policy_names

    assert choices.POLICIES == policy_names()
    assert set(choices.VIEWER_POLICIES) <= set(choices.POLICIES)


def test_the_viewer_starts_with_what_its_state_accepts():
    from clipvol.errors import ParameterError
    from clipvol.viewer.controls import ViewState

    for name in choices.VIEWER_POLICIES:
        ViewState(num_levels=3, mode=name)
    with pytest.raises(ParameterError):
        ViewState(num_levels=3, mode=next(p for p in choices.POLICIES if p not in choices.VIEWER_POLICIES))


def test_views_are_the_tables_of_named_views():
    from clipvol.scene import views

    assert choices.VIEWS == tuple(views.ANATOMICAL_VIEWS) + tuple(views.ALIASES)
    assert set(views.ARRAY_VIEWS) <= set(choices.VIEWS)


def test_camera_paths_are_those_make_path_draws():
    from clipvol.scene import paths

    assert set(choices.CAMERA_PATHS) == set(paths.PATHS)


def test_presets_build_and_opacity_curves_are_the_tables():
    from clipvol.scene.transfer import OPACITY_CURVES, TransferFunction

    for name in choices.TF_PRESETS:
        assert TransferFunction.preset(name) is not None
    assert choices.OPACITY_CURVES == tuple(OPACITY_CURVES)


def test_render_params_fields_take_their_default_and_help_from_here():
    from clipvol.scene.params import RenderParams

    declared = {f.name: f for f in fields(RenderParams)}
    for name, (default, help) in choices.PARAM_FIELDS.items():
        assert declared[name].default == default, name
        assert RenderParams.help(name) == help, name
    assert getattr(RenderParams(), "mode") in choices.MODES


def test_remote_time_outs_are_the_byte_sources():
    from clipvol.paging import bytesource

    assert (bytesource.DEFAULT_CONNECT_TIMEOUT, bytesource.DEFAULT_READ_TIMEOUT) == \
        (choices.DEFAULT_CONNECT_TIMEOUT, choices.DEFAULT_READ_TIMEOUT)
