"""Where an algorithm's tensors live, and its gradient step replayed as one CUDA graph.

A small-network update on a GPU is bound by kernel launches, not arithmetic: about a hundred
small kernels, each launched from Python. Captured once as a CUDA graph, the whole update
(three losses, their backward passes, three Adam steps and the Polyak average) is replayed
by one launch. On CPU the same body simply runs, so CPU curves stay bit for bit what they
were.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator

import torch

from baselines.common.checkpoint import CheckpointDeviceError

DEVICES = ("auto", "cpu", "cuda")
GRAPH_WARMUP_UPDATES = 3  # eager updates before capture: optimiser state and cuBLAS set up


class DeviceUnavailableError(RuntimeError):
    pass


_flushing = False  # torch has no getter for the flag; only flush_denormals sets it


@contextlib.contextmanager
def flush_denormals(enabled: bool = True) -> Iterator[None]:
    """Inside the block this thread's float arithmetic treats denormals as zero
    (``enabled``) or not, and afterwards as before. Denormals arise where values decay
    towards zero (Adam's moments of dead units, gradients through a saturated tanh), and x86
    arithmetic on them is about ten times slower: DDPGfD slowed tenfold after its first
    MountainCar episode, a SAC seed batch on Walker2d by a sixth. Every registered trainer
    runs inside one (``baselines.registry``; runs use one torch thread, the caller's).
    Where the CPU cannot flush (not x86 with SSE3) the block computes with denormals."""
    global _flushing
    before = _flushing
    _flushing = torch.set_flush_denormal(enabled) and enabled
    try:
        yield
    finally:
        torch.set_flush_denormal(before)
        _flushing = before


def can_flush_denormals() -> bool:
    """Whether this CPU flushes denormals inside ``flush_denormals`` (recorded in each run's
    provenance); the flag is left as it was."""
    supported = torch.set_flush_denormal(True)
    torch.set_flush_denormal(_flushing)
    return bool(supported)


def resolve_device(requested: str, has_gpu_path: bool) -> str:
    """The device a run of an algorithm uses: ``auto`` takes the GPU when there is one and
    the algorithm has a GPU path; ``cuda`` insists on a GPU (for those algorithms) and fails
    without one; ``cpu`` never uses one. Algorithms without a GPU path always run on CPU."""
    if requested not in DEVICES:
        raise ValueError(f"unknown device '{requested}'; choose one of {', '.join(DEVICES)}")
    if requested == "cuda" and not torch.cuda.is_available():
        raise DeviceUnavailableError(
            f"--device cuda was asked for, but torch sees no CUDA GPU (torch {torch.__version__})"
        )
    if requested == "cpu" or not has_gpu_path:
        return "cpu"
    return "cuda" if torch.cuda.is_available() else "cpu"


def worker_devices(requested: str, workers: int, gpu_workers: int | None = None) -> list[str]:
    """The device of each of ``workers`` local processes of a grid: every one on the device
    ``requested`` resolves to, unless ``gpu_workers`` limits those on the GPU (with ``auto``),
    the rest training on the CPU cores.

    The limit trades reproducibility for throughput: one GPU serves about two runs at once,
    since the small kernels of several processes take turns on it. Measured on an H100 with
    16 cores (reports/bench/bench_gpu.json, Hopper twin-Q SAC): one run alone 822 env steps/s;
    16 seeds on 16 processes all on the GPU 1318 in all; 32 seeds on 16 processes with 0, 1,
    2 or 4 of them on the GPU 1541, 1689, 2015 and 1930. But with a limit, which runs land on
    the GPU depends on scheduling, so runs compared bit for bit (Fig. 4's identical start,
    the ablation's T2 = 0 against SAC) may then differ.
    """
    if gpu_workers is not None and gpu_workers < 0:
        raise ValueError(f"the number of GPU workers must be >= 0, got {gpu_workers}")
    device = resolve_device(requested, has_gpu_path=True)
    if device == "cpu" or gpu_workers is None or requested == "cuda":
        return [device] * workers
    on_gpu = min(gpu_workers, workers)
    return ["cuda"] * on_gpu + ["cpu"] * (workers - on_gpu)


def device_kind(recorded: str) -> str:
    """``cuda`` or ``cpu``, from a device as provenance records it (``describe_device``)."""
    return "cuda" if recorded.startswith("cuda") else "cpu"


def resume_device(device: str, saved_on: str | None, follow: bool, what: str) -> str:
    """The device a run resumes on: ``device``, unless its checkpoint was made on the other
    kind (``saved_on``; None: no checkpoint). Then the checkpoint's kind when ``follow`` and
    this machine has it, since CPU and CUDA noise streams differ in kind; else
    :class:`CheckpointDeviceError` naming ``what`` and the way out."""
    if saved_on is None or saved_on == device:
        return device
    if follow and (saved_on == "cpu" or torch.cuda.is_available()):
        return saved_on
    raise CheckpointDeviceError(
        f"{what} has a checkpoint made on {saved_on}, and would train on {device}; resume it "
        f"with --device {saved_on} (or auto), or delete it to start over"
    )


def describe_device(device: str) -> str:
    """``cpu``, or ``cuda`` with the GPU's name, for provenance."""
    if device.startswith("cuda"):
        return (
            f"cuda ({torch.cuda.get_device_name(torch.device(device))}, CUDA {torch.version.cuda})"
        )
    return device


StepBody = Callable[..., dict[str, torch.Tensor]]


class GraphedStep:
    """Calls ``body(**inputs)``: eagerly on CPU (or with graphs off), and on CUDA as a graph
    captured after a few eager calls and replayed on copies of the inputs.

    ``body`` must take tensors of fixed shapes and return detached tensors; the returned
    tensors are overwritten by the next call. Random numbers it draws itself must come from
    the default CUDA generator (graph capture advances its offset on every replay); the
    one-run agents draw theirs outside and pass them in.
    """

    def __init__(self, body: StepBody, device: torch.device, use_graph: bool = True):
        self.body = body
        self.device = device
        self.use_graph = use_graph and device.type == "cuda"
        self.calls = 0
        self.graph: torch.cuda.CUDAGraph | None = None
        self.static_inputs: dict[str, torch.Tensor] = {}
        self.static_outputs: dict[str, torch.Tensor] = {}

    def __call__(self, **inputs: torch.Tensor) -> dict[str, torch.Tensor]:
        """Run the body on ``inputs``, which may live on the CPU or on the device."""
        if not self.use_graph:
            return self.body(**self._on_device(inputs))
        self.calls += 1
        if self.calls <= GRAPH_WARMUP_UPDATES:
            # warm-up on a side stream, as CUDA graph capture requires; real updates
            side = torch.cuda.Stream()
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                outputs = self.body(**self._on_device(inputs))
            torch.cuda.current_stream().wait_stream(side)
            return outputs
        if self.graph is None:
            self._capture(self._on_device(inputs))
        for name, value in inputs.items():
            self.static_inputs[name].copy_(value, non_blocking=True)
        self.graph.replay()
        return self.static_outputs

    def _on_device(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {name: value.to(self.device, non_blocking=True) for name, value in inputs.items()}

    def _capture(self, inputs: dict[str, torch.Tensor]) -> None:
        """Record the body once (recording runs nothing); the caller then replays it."""
        self.static_inputs = {name: value.clone() for name, value in inputs.items()}
        self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self.graph):
            self.static_outputs = self.body(**self.static_inputs)


def make_adam(
    params: Iterable[torch.nn.Parameter], lr: float, device: torch.device, fused_on_cpu: bool
) -> torch.optim.Adam:
    """Adam as the harness uses it: on CUDA fused and capturable (a replayed graph needs the
    step count on the device); on CPU fused only where the algorithm always was, so that
    CPU curves do not move."""
    if device.type == "cuda":
        return torch.optim.Adam(params, lr=lr, fused=True, capturable=True)
    return torch.optim.Adam(params, lr=lr, fused=True if fused_on_cpu else None)
