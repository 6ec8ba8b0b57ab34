"""The harness's check of ``--device``, shared by the runner and the experts."""

from __future__ import annotations

from baselines.common.device import DeviceUnavailableError, resolve_device
from replicate.errors import HarnessError


def check_device(requested: str) -> None:
    """Fail early, with the fix, when ``requested`` (``--device``) cannot be honoured here."""
    try:
        resolve_device(requested, has_gpu_path=True)
    except (ValueError, DeviceUnavailableError) as exc:
        raise HarnessError(
            str(exc), "pass --device auto (GPU when present) or --device cpu"
        ) from None
