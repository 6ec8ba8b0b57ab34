"""A paper's claims as data: a TOML declaration read into claims, parts, checks and
preconditions, validated field by field. No claim's logic lives in Python: the check kinds
are small pure functions in ``replicate.claims.judge``; which algorithms, envs, measures, margins
and levels they use is in the file.

A malformed or inconsistent declaration stops with one line naming the claim and the
field (``DeclarationError``, a ``HarnessError``: exit status 2 from the command line).
"""

from __future__ import annotations

import subprocess
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from replicate.errors import HarnessError
from replicate.store.measures import DEFAULT_DECLARATION

CHECK_KINDS = ("mean", "difference", "escape")
MEASURES = ("final_return", "area", "instability")
PRECONDITION_KINDS = ("stuck_seed",)
RUN_SETS = ("fig3", "fig4")  # which of a profile's grids a claim is judged on

_CHECK_FIELDS = {
    "kind",
    "algo",
    "other",
    "env",
    "measure",
    "above",
    "within",
    "smallest_effect",
    "below",
    "needs_published_reach",
}
_PRECONDITION_FIELDS = {"kind", "algo", "env", "measure", "below", "statement"}
_PART_FIELDS = {"id", "statement", "check"}
_CLAIM_FIELDS = {
    "id",
    "title",
    "source",
    "quote",
    "runs",
    "budget_note",
    "part",
    "precondition",
}
_TOP_FIELDS = {"paper", "measures", "tests", "demonstrations", "claim"}


class DeclarationError(HarnessError):
    """A declaration file that cannot be judged with."""


@dataclass(frozen=True)
class CheckSpec:
    """One check as declared: a measure of ``algo``'s runs on ``env`` (or its difference
    from ``other``'s) against a threshold (``above``) or inside a band (``within``)."""

    kind: str
    algo: str
    env: str
    measure: str
    other: str | None = None
    above: float | None = None
    within: tuple[float, float] | None = None
    smallest_effect: float | None = None
    below: float | None = None  # escape: the level under which a seed is stuck
    needs_published_reach: bool = False  # not testable where no published SAC reaches it


@dataclass(frozen=True)
class Precondition:
    """What must be observed for the claim to be testable at all."""

    kind: str
    algo: str
    env: str
    measure: str
    below: float
    statement: str


@dataclass(frozen=True)
class PartSpec:
    id: str
    statement: str
    checks: tuple[CheckSpec, ...]


@dataclass(frozen=True)
class ClaimSpec:
    id: int
    title: str
    source: str
    quote: str
    runs: str
    parts: tuple[PartSpec, ...]
    preconditions: tuple[Precondition, ...] = ()
    budget_note: str | None = None

    @property
    def envs(self) -> tuple[str, ...]:
        """Every env its checks and preconditions read, in declared order."""
        found = [c.env for p in self.parts for c in p.checks]
        found += [p.env for p in self.preconditions]
        return tuple(dict.fromkeys(found))

    @property
    def checks(self) -> list[CheckSpec]:
        return [c for p in self.parts for c in p.checks]


@dataclass(frozen=True)
class Version:
    """The declaration's version: the last commit that changed its file, and when."""

    commit: str | None
    date: str | None  # ISO 8601, the commit's author date

    @property
    def short(self) -> str:
        if not self.commit:
            return "uncommitted"
        return f"{self.commit[:10]} of {self.date[:10]}" if self.date else self.commit[:10]


@dataclass(frozen=True)
class Declaration:
    path: Path
    key: str
    title: str
    measure_quote: str
    confidence: float
    demonstrations: dict[str, float]
    claims: tuple[ClaimSpec, ...]

    def claim(self, claim_id: int) -> ClaimSpec:
        return next(c for c in self.claims if c.id == claim_id)

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(c.id for c in self.claims)


def _fail(path: Path, where: str, problem: str) -> DeclarationError:
    return DeclarationError(
        f"{path.name}: {where}: {problem}",
        f"correct {path} (docs/claims.md describes its fields)",
    )


def _unknown_fields(path: Path, where: str, table: dict[str, Any], allowed: Iterable[str]) -> None:
    extra = sorted(set(table) - set(allowed))
    if extra:
        raise _fail(
            path, where, f"unknown field '{extra[0]}' (known: {', '.join(sorted(allowed))})"
        )


def _number(path: Path, where: str, table: dict[str, Any], key: str) -> float | None:
    value = table.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(path, where, f"field '{key}' must be a number, not {value!r}")
    return float(value)


def _text(path: Path, where: str, table: dict[str, Any], key: str) -> str:
    value = table.get(key)
    if not isinstance(value, str) or not value.strip():
        raise _fail(path, where, f"field '{key}' is missing or empty")
    return value


def _one_of(path: Path, where: str, key: str, value: Any, known: Iterable[str]) -> str:
    known = list(known)
    if value not in known:
        raise _fail(
            path, where, f"field '{key}': unknown {key} {value!r} (known: {', '.join(known)})"
        )
    return value


def _check(
    path: Path, where: str, table: dict[str, Any], algos: set[str], envs: set[str]
) -> CheckSpec:
    _unknown_fields(path, where, table, _CHECK_FIELDS)
    kind = _one_of(path, where, "kind", table.get("kind"), CHECK_KINDS)
    algo = _one_of(path, where, "algo", table.get("algo"), sorted(algos))
    env = _one_of(path, where, "env", table.get("env"), sorted(envs))
    measure = _one_of(path, where, "measure", table.get("measure"), MEASURES)
    other = table.get("other")
    if kind in ("difference", "escape"):
        other = _one_of(path, where, "other", other, sorted(algos))
        if other == algo:
            raise _fail(path, where, f"field 'other' names the same algorithm as 'algo' ({algo})")
    elif other is not None:
        raise _fail(path, where, f"field 'other' is for a difference, not a {kind} check")
    above = _number(path, where, table, "above")
    within = table.get("within")
    if within is not None:
        if (
            not isinstance(within, list)
            or len(within) != 2
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in within)
            or not within[0] < within[1]
        ):
            raise _fail(
                path, where, f"field 'within' must be [low, high] with low < high, not {within!r}"
            )
        within = (float(within[0]), float(within[1]))
    below = _number(path, where, table, "below")
    if kind == "escape":
        if below is None or above is not None or within is not None:
            raise _fail(path, where, "an escape check takes 'below' (the stuck level) alone")
    elif (above is None) == (within is None):
        raise _fail(path, where, "give exactly one of 'above' (a threshold) and 'within' (a band)")
    effect = _number(path, where, table, "smallest_effect")
    if effect is not None and (effect <= 0 or within is not None):
        raise _fail(path, where, "field 'smallest_effect' must be positive, beside 'above'")
    reach = table.get("needs_published_reach", False)
    if not isinstance(reach, bool):
        raise _fail(path, where, "field 'needs_published_reach' must be true or false")
    return CheckSpec(kind, algo, env, measure, other, above, within, effect, below, reach)


def _precondition(
    path: Path, where: str, table: dict[str, Any], algos: set[str], envs: set[str]
) -> Precondition:
    _unknown_fields(path, where, table, _PRECONDITION_FIELDS)
    kind = _one_of(path, where, "kind", table.get("kind"), PRECONDITION_KINDS)
    below = _number(path, where, table, "below")
    if below is None:
        raise _fail(path, where, "field 'below' (the stuck level) is missing")
    return Precondition(
        kind,
        _one_of(path, where, "algo", table.get("algo"), sorted(algos)),
        _one_of(path, where, "env", table.get("env"), sorted(envs)),
        _one_of(path, where, "measure", table.get("measure"), MEASURES),
        below,
        _text(path, where, table, "statement"),
    )


def _known_algorithms() -> set[str]:
    from baselines.registry import algorithms

    return set(algorithms())


def _known_envs() -> set[str]:
    from envs import ENV_SPECS

    return {spec.env_id for spec in ENV_SPECS.values()}


def load_declaration(
    path: Path = DEFAULT_DECLARATION,
    algos: set[str] | None = None,
    envs: set[str] | None = None,
) -> Declaration:
    """Read and validate a declaration file; ``algos`` and ``envs`` default to the
    registered algorithms and the env table."""
    path = Path(path)
    if not path.is_file():
        raise DeclarationError(f"no declaration file at {path}", "give the path of a .toml file")
    try:
        with open(path, "rb") as handle:
            data = tomllib.load(handle)
    except tomllib.TOMLDecodeError as exc:
        raise _fail(path, "TOML", str(exc)) from None
    algos = _known_algorithms() if algos is None else set(algos)
    envs = _known_envs() if envs is None else set(envs)
    _unknown_fields(path, "top level", data, _TOP_FIELDS)
    paper = data.get("paper", {})
    key = _text(path, "[paper]", paper, "key")
    confidence = _number(path, "[tests]", data.get("tests", {}), "confidence") or 0.95
    if not 0.5 < confidence < 1:
        raise _fail(
            path, "[tests]", f"field 'confidence' must lie between 0.5 and 1, not {confidence}"
        )
    demonstrations = {}
    for env, value in data.get("demonstrations", {}).items():
        _one_of(path, "[demonstrations]", "env", env, sorted(envs))
        demonstrations[env] = _number(path, "[demonstrations]", {env: value}, env)
    claims, seen = [], set()
    for index, table in enumerate(data.get("claim", []), start=1):
        claim_id = table.get("id")
        where = f"claim {claim_id if claim_id is not None else f'#{index}'}"
        _unknown_fields(path, where, table, _CLAIM_FIELDS)
        if isinstance(claim_id, bool) or not isinstance(claim_id, int) or claim_id in seen:
            raise _fail(path, where, "field 'id' must be an integer no other claim has")
        seen.add(claim_id)
        runs = _one_of(path, where, "runs", table.get("runs", "fig3"), RUN_SETS)
        parts, part_ids = [], set()
        for part in table.get("part", []):
            part_where = f"{where}, part {part.get('id', '?')}"
            _unknown_fields(path, part_where, part, _PART_FIELDS)
            part_id = _text(path, part_where, part, "id")
            if part_id in part_ids:
                raise _fail(path, part_where, "field 'id' repeats another part's")
            part_ids.add(part_id)
            checks = part.get("check", [])
            if not checks:
                raise _fail(path, part_where, "a part with no check")
            parts.append(
                PartSpec(
                    part_id,
                    _text(path, part_where, part, "statement"),
                    tuple(
                        _check(path, f"{part_where}, check {k}", c, algos, envs)
                        for k, c in enumerate(checks, start=1)
                    ),
                )
            )
        if not parts:
            raise _fail(path, where, "a claim with no part")
        claims.append(
            ClaimSpec(
                claim_id,
                _text(path, where, table, "title"),
                _text(path, where, table, "source"),
                _text(path, where, table, "quote"),
                runs,
                tuple(parts),
                tuple(
                    _precondition(path, f"{where}, precondition {k}", p, algos, envs)
                    for k, p in enumerate(table.get("precondition", []), start=1)
                ),
                table.get("budget_note"),
            )
        )
    if not claims:
        raise _fail(path, "top level", "no [[claim]]")
    return Declaration(
        path,
        key,
        _text(path, "[paper]", paper, "title"),
        paper.get("measure_quote", ""),
        confidence,
        demonstrations,
        tuple(claims),
    )


def declaration_version(path: Path = DEFAULT_DECLARATION) -> Version:
    """The last commit that changed ``path`` and its date; no commit where git is missing,
    the file is untracked, or it has uncommitted changes (then it is "uncommitted")."""
    path = Path(path).resolve()

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args, "--", path.name],
            cwd=path.parent,
            capture_output=True,
            text=True,
            check=True,
        ).stdout

    try:
        dirty = git("status", "--porcelain").strip()
        logged = git("log", "-1", "--format=%H %aI").split()
    except (OSError, subprocess.CalledProcessError):
        return Version(None, None)
    if dirty or len(logged) != 2:
        return Version(None, None)
    return Version(logged[0], logged[1])


def trained_before(started: Iterable[str | None], version: Version) -> int:
    """How many runs (by their ``started_utc``) began before the declaration's version."""
    if not version.date:
        return 0
    fixed = datetime.fromisoformat(version.date)
    return sum(1 for s in started if s and datetime.fromisoformat(s) < fixed)
