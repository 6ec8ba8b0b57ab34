"""A run's recorded git revision is dirty for changed training code, not for docs, runs or
reports."""

import subprocess

from replicate.store.provenance import revision_at


def _git(where, *args):
    subprocess.run(["git", "-C", str(where), *args], check=True, capture_output=True)


def test_revision_is_dirty_for_code_changes_only(tmp_path, monkeypatch):
    for name in ("GIT_DIR", "GIT_WORK_TREE", "GIT_INDEX_FILE", "GIT_LITERAL_PATHSPECS"):
        monkeypatch.delenv(name, raising=False)
    tracked = ("replicate/code.py", "baselines/sac.py", "runs/r/curve.csv", "docs/a.md")
    for name in (*tracked, "reports/fig3/summary.json", "README.md"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("0\n")
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(
        tmp_path,
        "-c",
        "user.name=t",
        "-c",
        "user.email=t@t",
        "-c",
        "commit.gpgsign=false",
        "commit",
        "-qm",
        "one",
    )
    head = subprocess.run(
        ["git", "-C", str(tmp_path), "rev-parse", "HEAD"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    (tmp_path / "runs/r/curve.csv").write_text("1\n")
    (tmp_path / "reports/fig3/summary.json").write_text("1\n")
    (tmp_path / "replicate/untracked.py").write_text("1\n")
    (tmp_path / "docs/a.md").write_text("1\n")
    (tmp_path / "README.md").write_text("1\n")
    assert (
        revision_at(tmp_path / "replicate") == head
    )  # asked from a subfolder, as the package does
    (tmp_path / "baselines/sac.py").write_text("1\n")
    assert revision_at(tmp_path / "runs") == head + "+dirty"
