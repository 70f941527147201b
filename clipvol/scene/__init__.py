"""Stage 3, scene: what a frame should show, as pure numpy (no GL, no threads).

Holds the camera and its frustum (``camera``), regions of interest and clip planes (``geometry``),
transfer functions (``transfer``), the one frozen set of render parameters (``params``), the
selection traversal over the brick octree and its interchangeable policies (``selection``), camera
paths for flythroughs (``paths``) and image metrics (``metrics``). It imports bricking (the
pyramid) and defines the residency contract it needs itself, never paging, moderngl or glfw, so
every decision a renderer makes can be tested and explained without a context.
"""

# Fill the policy registry (clipvol.scene.policy_registry) before anything can build a RenderParams:
# params is importable only through this package, and validates its policy against the registry.
from .selection import policies as _policies  # noqa: E402,F401
