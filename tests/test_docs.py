"""README.md and docs/ against what the runs gave: the verdict table equals the claims of
the committed summaries, the numbers quoted from runs equal the summaries' (and the
demonstrations' and benches' records), and every link leads somewhere. Each failure says
what the summaries hold now, so that the text can be brought back in line."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")
MC, HOPPER, WALKER, CHEETAH, ANT = (
    "MountainCarContinuous-v0",
    "Hopper-v5",
    "Walker2d-v5",
    "HalfCheetah-v5",
    "Ant-v5",
)
LABELS = {
    "sac": "SAC",
    "drl-eg": "DRL-EG",
    "drl-eg-gmm": "DRL-EG-GMM",
    "ddpgfd": "DDPGfD",
    "ppo": "PPO",
    "ppo-bc": "PPO+BC",
    "ibrl": "IBRL",
    "rlpd": "RLPD",
    "jsrl": "JSRL",
}


def summary(report: str) -> dict:
    return json.loads((ROOT / report / "summary.json").read_text())


def claims_of(data: dict) -> list[dict]:
    return data.get("claims") or ([data["claim"]] if "claim" in data else [])


def verdict_head(verdict: str) -> str:
    """The verdict without its reason ('not judged: no runs of ...' -> 'not judged')."""
    return verdict.split(":")[0].strip()


def flat(path: Path) -> str:
    """The text with every run of whitespace as one space: prose wraps anywhere."""
    return " ".join(path.read_text().split())


def table_rows(text: str, header_start: str) -> tuple[list[str], list[list[str]]]:
    """The header cells and the body rows of the first Markdown table whose header line
    starts with ``header_start``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header_start))
    cells = [
        [c.strip() for c in line.strip().strip("|").split("|")]
        for line in lines[start:]
        if line.startswith("|")
    ]
    end = next(
        (i for i, line in enumerate(lines[start:]) if not line.startswith("|")), len(lines) - start
    )
    cells = cells[:end]
    return cells[0], cells[2:]


def f1(x: float) -> str:
    return f"{x:.1f}"


def assert_quoted(text: str, expected: str, where: str) -> None:
    assert expected in text, f"{where} should quote '{expected}' (what the summaries hold now)"


# --- README: the claims x profiles table -------------------------------------------------


def readme_table() -> tuple[list[str], dict[int, list[str]]]:
    header, rows = table_rows(README.read_text(), "| claim |")
    profiles = [cell.split(":")[0].strip() for cell in header[1:]]
    by_claim = {int(row[0].split(".")[0]): row[1:] for row in rows}
    return profiles, by_claim


def tracked_reports() -> set[Path]:
    """The reports git tracks: a smoke or --out report written into the tree is not one."""
    import subprocess

    try:
        listed = subprocess.run(
            ["git", "ls-files", "reports"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return {ROOT / name for name in listed}


def committed_summaries_with_claims() -> list[Path]:
    found = sorted(ROOT.glob("reports/*/summary.json")) + sorted(
        ROOT.glob("reports/*/*/summary.json")
    )
    tracked = tracked_reports()
    return [p for p in found if p in tracked and claims_of(json.loads(p.read_text()))]


def names(text: str, verdict: str) -> bool:
    """Whether a table's ``text`` names ``verdict``: the whole verdict without its reason,
    or its first words ('not judged' for 'not judged at this profile's budget')."""
    head = verdict_head(verdict)
    return head == text or head.startswith(text + " ")


def test_the_readme_verdicts_are_the_summaries_verdicts():
    profiles, by_claim = readme_table()
    assert sorted(by_claim) == [1, 2, 3, 4, 5]
    for claim_id, cells in by_claim.items():  # every verdict linked is its report's
        for profile, cell in zip(profiles, cells):
            links = LINK.findall(cell)
            assert links, f"claim {claim_id}, {profile}: no verdict linked"
            for text, target in links:
                report = str(Path(target.split("#")[0]).parent)
                data = summary(report)
                assert data["profile"] == profile, f"{target} is not a {profile} report"
                (claim,) = [c for c in claims_of(data) if c["id"] == claim_id]
                assert names(text, claim["verdict"]), (
                    f"README, claim {claim_id} at {profile}: '{text}', but {report}/summary.json "
                    f"says '{verdict_head(claim['verdict'])}'"
                )
    for path in committed_summaries_with_claims():  # and every report's verdict is there
        data = json.loads(path.read_text())
        report = str(path.parent.relative_to(ROOT))
        assert data["profile"] in profiles, f"README's table has no column for {report}"
        for claim in claims_of(data):
            cell = by_claim[claim["id"]][profiles.index(data["profile"])]
            assert any(names(text, claim["verdict"]) for text, _ in LINK.findall(cell)), (
                f"README's table does not give {report}'s verdict on claim {claim['id']}: "
                f"'{verdict_head(claim['verdict'])}'"
            )


def test_the_readme_keeps_the_two_commands_and_its_length():
    lines = README.read_text().splitlines()
    assert "python3 -m pip install nox && python3 -m nox -s tests" in lines  # .ci/run's
    assert "python3 -m pip install nox && python3 -m nox -s replicate-fig3" in lines
    assert len(lines) <= 250
    # the GPU path's check is named where a user decides to train on a GPU
    assert "benchmarks/gpu_checks.py" in README.read_text()
    assert (ROOT / "benchmarks/gpu_checks.py").is_file()


# --- docs/results.md: numbers from the runs ----------------------------------------------

RESULTS = DOCS / "results.md"


def finals(report: str) -> dict[tuple[str, str], dict]:
    return {(r["env_id"], r["algo"]): r for r in summary(report)["final_returns"]}


def mean_and_seeds(row: dict) -> str:
    return f"{f1(row['mean'])} ({', '.join(f1(x) for x in row['finals'])})"


def test_quick_fig3_final_returns_are_the_summarys():
    text, rows = flat(RESULTS), finals("reports/fig3")
    for algo in ("drl-eg", "ppo", "ppo-bc", "ddpgfd", "drl-eg-gmm"):
        assert_quoted(text, f"{LABELS[algo]} {mean_and_seeds(rows[(MC, algo)])}", "results.md")
    assert max(abs(x) for x in rows[(MC, "sac")]["finals"]) < 0.05  # "SAC 0.0 on every seed"


def test_the_reduced_fig3_table_is_the_summarys():
    rows = finals("reports/reduced/fig3")
    header, body = table_rows(RESULTS.read_text(), "| env | SAC |")
    algos = {label: algo for algo, label in LABELS.items()}
    envs = {"Hopper": HOPPER, "Walker2d": WALKER, "HalfCheetah": CHEETAH, "Ant": ANT}
    seen = set()
    for row in body:
        env_id = envs[row[0]]
        for label, cell in zip(header[1:], row[1:]):
            algo = algos[label]
            expected = rows[(env_id, algo)]
            wanted = mean_and_seeds(expected) if "(" in cell else f1(expected["mean"])
            assert cell == wanted, f"results.md, {env_id} {label}: '{cell}', summary: '{wanted}'"
            seen.add((env_id, algo))
    mujoco = {key for key in rows if key[0] != MC}
    assert seen == mujoco, f"results.md's table lacks {sorted(mujoco - seen)}"


@pytest.mark.parametrize("report", ["reports/fig4", "reports/reduced/fig4"])
def test_fig4_pairs_are_the_summarys(report):
    text, data = flat(RESULTS), summary(report)
    by_seed = sorted(data["rows"], key=lambda r: r["seed"])
    sac = ", ".join(f"{r['sac']:.0f}" for r in by_seed)
    drl = ", ".join(f"{r['drl']:.0f}" for r in by_seed)
    assert_quoted(text, f"SAC {sac}; DRL-EG {drl}", "results.md")
    assert_quoted(
        text,
        f"mean paired difference {data['paired']['value']:.0f}"
        if report == "reports/fig4"
        else f"(mean {data['paired']['value']:.0f})",
        "results.md",
    )
    if report == "reports/reduced/fig4":
        differences = ", ".join(f"{r['difference']:+.0f}" for r in by_seed)
        assert_quoted(text, f"seed {differences}", "results.md")


def test_the_threshold_ablations_are_the_summarys():
    text = flat(RESULTS)
    quick = {r["label"]: r for r in summary("reports/ablate-threshold")["rows"]}
    assert_quoted(
        text,
        f"area under the curve {f1(quick['0.01']['auc']['mean'])} against "
        f"{f1(quick['0.05']['auc']['mean'])}",
        "results.md",
    )
    assert_quoted(text, f"mean {f1(quick['0.01']['final']['mean'])})", "results.md")
    assert_quoted(text, f"final {f1(quick['0.05']['final']['mean'])}", "results.md")

    ant, walker = (summary(f"reports/reduced/ablate-threshold-{e}") for e in ("ant", "walker2d"))
    assert_quoted(
        text,
        f"SAC: Ant {f1(ant['sac_final_mean'])}, Walker2d {f1(walker['sac_final_mean'])}",
        "results.md",
    )
    _, body = table_rows(RESULTS.read_text(), "| T2 |")
    for row in body:
        for data, cell in ((ant, row[2]), (walker, row[4])):
            (point,) = [r for r in data["rows"] if r["label"].split(" ")[0] == row[0]]
            assert cell == f1(point["final"]["mean"]), f"results.md, T2 {row[0]}: {cell}"
    assert len(body) == len(ant["rows"]) == len(walker["rows"])

    gains = {r["setting"]: r for r in ant["t2_rule"]["rows"]}
    one = gains["1x"]
    quoted = (
        f"1x {one['gain']:.3f} (Ant {one['per_env'][ANT]['gain']:+.3f}, Walker2d "
        f"{one['per_env'][WALKER]['gain']:+.3f}), 4x {gains['4x']['gain']:.3f}, 16x "
        f"{gains['16x']['gain']:.3f}"
    )
    for doc in (RESULTS, DOCS / "decisions.md"):
        assert_quoted(flat(doc), quoted, doc.name)
        assert_quoted(flat(doc), f"{gains['64x']['gain']:.3f}", doc.name)
    assert f"{gains['64x']['gain']:.3f}" == f"{gains['always']['gain']:.3f}"
    assert ant["t2_rule"]["choice"] == "1x"


def test_the_comparisons_are_the_summarys():
    text = flat(RESULTS)
    order = ("sac", "drl-eg", "ibrl", "rlpd", "jsrl", "ddpgfd")
    quick = {c["algo"]: c["final_normalised"] for c in summary("reports/rlfd")["cells"]}
    assert_quoted(text, ", ".join(f"{LABELS[a]} {quick[a]:.3f}" for a in order), "results.md")

    reduced = summary("reports/reduced/rlfd")
    iqm = {a: v[0] for a, v in reduced["aggregate"]["iqm"].items()}
    assert_quoted(
        text,
        ", ".join(
            f"{LABELS[a]} {iqm[a]:.2f}" for a in ("ibrl", "ddpgfd", "rlpd", "drl-eg", "jsrl", "sac")
        ),
        "results.md",
    )
    beats = {i["other"]: i["value"] for i in reduced["aggregate"]["improvement"]}
    assert_quoted(
        text,
        f"beats SAC is {beats['sac']:.2f}, "
        + ", ".join(f"{LABELS[a]} {beats[a]:.2f}" for a in ("ibrl", "rlpd", "jsrl", "ddpgfd")),
        "results.md",
    )
    cells = {(c["env_id"], c["algo"]): c["final_normalised"] for c in reduced["cells"]}
    cart, cup = "dm_control/cartpole-swingup_sparse-v0", "dm_control/ball_in_cup-catch-v0"
    for quoted in (
        f"IBRL ({cells[(cart, 'ibrl')]:.3f} normalised",
        f"DDPGfD ({cells[(cart, 'ddpgfd')]:.3f})",
        f"JSRL {cells[(cart, 'jsrl')]:.3f}",
        f"SAC's to the last digit ({cells[(cup, 'drl-eg')]:.3f} normalised",
        f"RLPD ended at {cells[(cup, 'rlpd')]:.3f}",
        f"DDPGfD {cells[(cup, 'ddpgfd')]:.3f}, IBRL {cells[(cup, 'ibrl')]:.3f}, "
        f"JSRL {cells[(cup, 'jsrl')]:.3f}",
        *(
            f"{env}: DRL-EG {cells[(env_id, 'drl-eg')]:.3f}"
            f"{' normalised' if env == 'Ant' else ''}, SAC "
            f"{cells[(env_id, 'sac')]:.3f}, DDPGfD {cells[(env_id, 'ddpgfd')]:.3f}"
            for env, env_id in (("Ant", ANT), ("Hopper", HOPPER))
        ),
    ):
        assert_quoted(text, quoted, "results.md")
    assert cells[(cart, "sac")] == cells[(cart, "drl-eg")] == 0.0
    assert cells[(cup, "sac")] == cells[(cup, "drl-eg")]  # the guider never acted


# --- docs/experts.md and docs/performance.md: the records behind them --------------------


def test_the_experts_table_is_the_demonstrations_record():
    from replicate.demos import default_demo_path, load_demos
    from replicate.figures.table1 import EXPERT_TARGETS

    _, body = table_rows((DOCS / "experts.md").read_text(), "| expert |")
    assert len(body) == 7
    for row in body:
        env_id = row[0].split(" ")[0]
        meta = load_demos(default_demo_path(env_id), env_id).metadata
        wanted = (
            f"{meta['expert_return_mean']:.1f} ± {meta['expert_return_std']:.1f} "
            f"({meta['expert_episodes']})"
        )
        assert row[3].startswith(wanted), f"experts.md, {env_id}: '{row[3]}', record: {wanted}"
        target = EXPERT_TARGETS.get(env_id)
        if target and meta["expert_return_mean"] < target:
            short = 1 - meta["expert_return_mean"] / target
            assert f"short by {short:.0%}" in row[3], f"experts.md, {env_id}: {short:.0%}"
        elif target:
            assert "target met" in row[3]


def test_the_seed_batch_benches_are_the_recorded_ones():
    """Every number quoted is the recorded one, and no cell waits for a measurement."""
    perf = (DOCS / "performance.md").read_text()
    assert "TO-MEASURE" not in perf
    _, body = table_rows(perf, "| per machine, env steps/s |")
    assert len(body) == 4
    cpu = json.loads((ROOT / "reports/bench/batched_cpu.json").read_text())["cpu"]
    one = "machine one run per process"
    for row, n in zip(body, (None, 2, 4, 8)):
        measured = cpu[one] if n is None else cpu[f"machine batched N={n} per process"]
        ratio = 1 if n is None else cpu[f"batched N={n} / one run per process"]
        for cell, recorded in ((row[1], f"{measured:.1f}"), (row[2], f"{ratio:.3g}")):
            assert cell == recorded, f"performance.md, {row[0]}: {cell}"

    gpu = json.loads((ROOT / "reports/bench/batched_gpu.json").read_text())["gpu_batched"]
    quoted = re.search(r"trained ([\d,]+) for 64 members", flat(DOCS / "performance.md"))
    recorded = gpu["sac Hopper-v5 N=64"]["env_steps_per_s"]
    assert quoted and abs(float(quoted[1].replace(",", "")) - recorded) <= 0.5


def test_the_compile_decision_and_the_step_profile_are_the_recorded_ones():
    bench = json.loads((ROOT / "reports/bench/bench.json").read_text())
    perf = flat(DOCS / "performance.md")
    decision = bench["compiled_step"]["decision"]
    assert ("Decision: not offered" in perf) == (not decision["pays"])
    profile = bench["cpu_step_profile"]
    quoted = f"{profile['step_ms']:.2f} / {profile['flop_ms_at_gemm_rate']:.2f} = "
    assert quoted + f"{profile['step / flop time']:.2f}" in perf
    for part, ms in profile["ms"].items():
        assert f"| {ms:.2f} |" in (DOCS / "performance.md").read_text(), part


# --- links ---------------------------------------------------------------------------------


def anchors(path: Path) -> set[str]:
    """The anchors a Markdown file's headings get on GitHub, or an HTML file's ids."""
    text = path.read_text()
    if path.suffix == ".html":
        return set(re.findall(r'id="([^"]+)"', text))
    found = set()
    for heading in re.findall(r"^#+ (.+)$", text, flags=re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        found.add(slug)
    return found


@pytest.mark.parametrize("page", [README, *sorted(DOCS.glob("*.md"))], ids=lambda p: p.name)
def test_every_link_leads_somewhere(page):
    for _, target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target):
            continue  # an outside address
        file, _, anchor = target.partition("#")
        path = (page.parent / file).resolve() if file else page
        assert path.exists(), f"{page.name}: {target} does not exist"
        if anchor:
            assert anchor in anchors(path), f"{page.name}: no anchor #{anchor} in {file}"
