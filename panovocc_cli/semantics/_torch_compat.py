"""Importing ``open_clip`` where torchvision's compiled extension cannot load (one documented workaround).

``open_clip`` imports ``torchvision``. A torchvision wheel built for another torch (the package index
offers only CUDA builds of torchvision, while a CPU-only machine runs the CPU build of torch) cannot
load its C extension; torchvision then still imports its Python part, whose ``_meta_registrations``
registers fake kernels for the operators ``torchvision::nms`` and ``torchvision::qnms`` and fails with
``RuntimeError: operator torchvision::nms does not exist``. CLIP never calls those operators.

:func:`import_open_clip` imports normally; only when that exact failure happens *and* torchvision
reports its extension unloaded (``torchvision.extension._has_ops() is False``) does it define the two
operator schemas (no kernel: calling them would still fail) and import again. Where torchvision works
(e.g. a CUDA machine with matching wheels) nothing is defined. The library object that holds the
definitions is kept for the life of the process (:data:`_SHIM`).
"""

from __future__ import annotations

import sys

from ..errors import PanovoccError

#: How to install the optional dependencies (in every "missing" message).
INSTALL_HINT = "pip install -e '.[clip]' (open-clip-torch==3.3.0 with a CPU or CUDA torch)"

#: The ``torch.library.Library`` holding the shim's operator schemas, or None when no shim was needed.
_SHIM = None

#: The operators torchvision's Python part registers fake kernels for, with their schemas.
SHIM_SCHEMAS = ("nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
                "qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")


def _is_missing_extension_error(err: BaseException) -> bool:
    """Whether ``err`` is torchvision's import failure for an unloadable C extension (and nothing else)."""
    ext = sys.modules.get("torchvision.extension")
    has_ops = getattr(ext, "_has_ops", None)
    return (isinstance(err, RuntimeError) and "operator torchvision::" in str(err)
            and "does not exist" in str(err) and has_ops is not None and not has_ops())


def import_torchvision():
    """``import torchvision``, with the operator-schema shim only when its C extension cannot load.

    Returns
    -------
    module : the ``torchvision`` module

    Raises
    ------
    RuntimeError, ImportError
        Any other import failure, unchanged.
    """
    global _SHIM
    try:
        import torchvision
        return torchvision
    except RuntimeError as err:
        if not _is_missing_extension_error(err):
            raise
    import torch

    # Python already dropped the modules whose import failed; the ones that loaded stay (re-running
    # them would register their kernels twice)
    if _SHIM is None:
        lib = torch.library.Library("torchvision", "DEF")
        for schema in SHIM_SCHEMAS:
            lib.define(schema)
        _SHIM = lib
    import torchvision
    return torchvision


def shim_active() -> bool:
    """Whether this process needed (and installed) the operator-schema shim."""
    return _SHIM is not None


def import_open_clip():
    """The ``open_clip`` module (torch and torchvision imported first, see the module docstring).

    Raises
    ------
    PanovoccError
        When torch or open_clip is not installed (one line with the install command).
    """
    try:
        import torch  # noqa: F401
    except ImportError:
        raise PanovoccError(f"the clip segmenter needs torch: {INSTALL_HINT}") from None
    try:
        import_torchvision()
    except ImportError:
        raise PanovoccError(f"the clip segmenter needs torchvision: {INSTALL_HINT}") from None
    try:
        import open_clip
    except ImportError:
        raise PanovoccError(f"the clip segmenter needs open_clip: {INSTALL_HINT}") from None
    return open_clip
