"""The plane of ``clipvol slice``'s flags: ``--plane AXIS=INDEX``, ``--axis NAME [--index I]
[--neurological]`` or ``--through X,Y,Z --normal X,Y,Z [--up X,Y,Z]``, as a
:class:`~clipvol.scene.plane.Plane` in the render frame.

Points and directions are in the store's world frame (``clipvol info``: patient RAS+ mm for NIfTI
and DICOM), converted by :mod:`clipvol.scene.cut`; only ``--plane`` and ``--index`` are voxel
indices. Errors name the flag.
"""

from __future__ import annotations

from clipvol.errors import ParameterError

__all__ = ["plane_from_args"]


def plane_from_args(pyramid, args, frame=None):
    """The :class:`~clipvol.scene.plane.Plane` the arguments name (default: the middle axial plane).

    With a patient ``frame`` the ``--axis`` presets (and the default) are the patient's planes in
    the radiological display (``--neurological`` for the other), :func:`clipvol.scene.views.anatomical_plane`.

    Errors name the command-line option (``--plane: index: expected 0..255 ...``)."""
    option = "--plane" if args.plane is not None else "--axis/--index" if args.axis is not None else "--through/--normal/--up"
    try:
        return _plane_from_args(pyramid, args, frame)
    except ParameterError as e:
        text = str(e)
        raise ParameterError(text if text.startswith("--") else f"{option}: {text}") from None


def _plane_from_args(pyramid, args, frame=None):
    from clipvol.scene.plane import AXIS_LETTERS, Plane

    given = [name for name, v in (("--plane", args.plane), ("--axis", args.axis), ("--through/--normal",
             args.through if args.through is not None else args.normal)) if v is not None]
    if len(given) > 1:
        raise ParameterError(f"plane: expected one of --plane, --axis, --through/--normal, got {' and '.join(given)}")
    if args.index is not None and args.axis is None:
        raise ParameterError("--index: expected together with --axis, got --index alone")
    from clipvol.scene.views import anatomical_plane, is_anatomical

    neuro = getattr(args, "neurological", False)
    if neuro and not (is_anatomical(frame) and args.plane is None and args.through is None and args.normal is None):
        raise ParameterError("--neurological: expected an --axis slice (or the default) of a store with a patient frame "
                             "(from NIfTI or DICOM), got " + ("a store without one" if not is_anatomical(frame)
                                                               else "--plane or --through/--normal"))
    if args.plane is not None:
        letter, _, index = args.plane.partition("=")
        if letter.strip().lower() not in AXIS_LETTERS or not index:
            raise ParameterError(f"--plane: expected AXIS=INDEX with AXIS x, y or z, got {args.plane!r}")
        try:
            i = float(index)
        except ValueError:
            raise ParameterError(f"--plane: expected a number after '=', got {args.plane!r}") from None
        return Plane.axis(pyramid, AXIS_LETTERS[letter.strip().lower()], i)
    if args.axis is not None:
        if is_anatomical(frame):
            return anatomical_plane(pyramid, frame, args.axis, args.index, "neurological" if neuro else "radiological")
        return Plane.axis(pyramid, args.axis, args.index)
    if args.through is not None or args.normal is not None:
        if args.through is None or args.normal is None:
            raise ParameterError("--through/--normal: expected both for an oblique plane, got one")
        return _world_plane(pyramid, frame, args.through, args.normal, args.up)
    if is_anatomical(frame):
        return anatomical_plane(pyramid, frame, "axial", None, "neurological" if neuro else "radiological")
    return Plane.axis(pyramid, "axial")


def _world_plane(pyramid, frame, origin, normal, up):
    """The render-frame plane of ``--through``/``--normal``/``--up`` given in the store's world frame.

    The image's right is ``normal x up`` in the world (so a mirrored store, LAS, is not shown
    mirrored); without ``--up`` a patient-frame store takes superior up (anterior for a plane
    facing superior), another store the preset up of the array axis nearest the normal.
    """
    import numpy as np

    from clipvol.scene.cut import direction_to_render, point_to_render
    from clipvol.scene.plane import Plane
    from clipvol.scene.views import is_anatomical

    o = point_to_render(pyramid, frame, origin, "--through")
    n_r = direction_to_render(pyramid, frame, normal, "--normal", normal=True)
    if up is None and not is_anatomical(frame):
        return Plane.through(o, n_r)
    n_w = np.asarray(normal, dtype=np.float64)
    if up is None:
        up = (0.0, 1.0, 0.0) if int(np.argmax(np.abs(n_w))) == 2 else (0.0, 0.0, 1.0)
    u_w = np.asarray(up, dtype=np.float64)
    r_w = np.cross(n_w, u_w)
    if not np.linalg.norm(r_w) > 1e-9 * np.linalg.norm(n_w) * max(1.0, float(np.linalg.norm(u_w))):
        raise ParameterError(f"--up: expected a vector not parallel to the normal {tuple(n_w.tolist())}, got {tuple(u_w.tolist())}")
    u_r = direction_to_render(pyramid, frame, u_w, "--up")
    r_r = direction_to_render(pyramid, frame, r_w, "--up")
    n = np.cross(u_r, r_r)  # so that Plane's right = normal x up is the world's right
    return Plane(tuple(o.tolist()), tuple((n / np.linalg.norm(n)).tolist()), tuple(u_r.tolist()))
