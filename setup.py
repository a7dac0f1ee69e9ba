"""The build's one hook: the git commit the package is built from, written as ``harness/_commit.txt``
into the wheel and the sdist, so a run's provenance names its commit when the package is installed
rather than run from its checkout (``harness.results.provenance``). Everything else is pyproject.toml."""

import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

HERE = Path(__file__).resolve().parent
COMMIT_FILE = Path("harness") / "_commit.txt"


def _checkout_commit() -> str | None:
    """The short commit of the checkout this file is the root of; None elsewhere (an sdist's tree, even
    one unpacked inside some other repository)."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--show-toplevel", "--short", "HEAD"],
            cwd=HERE,
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    lines = out.stdout.split()
    if out.returncode != 0 or len(lines) != 2 or Path(lines[0]).resolve() != HERE:
        return None
    return lines[1]


def _write_commit(root: Path) -> None:
    """Write the commit under ``root``: the checkout's, else the one an sdist carried in."""
    commit = _checkout_commit()
    carried = HERE / COMMIT_FILE
    if commit is None and carried.is_file():
        commit = carried.read_text().strip()
    if commit:
        (root / COMMIT_FILE).parent.mkdir(parents=True, exist_ok=True)
        (root / COMMIT_FILE).write_text(commit + "\n")


class BuildPyWithCommit(build_py):
    def run(self):
        super().run()
        if not self.editable_mode:  # an editable install reads its checkout's git at run time
            _write_commit(Path(self.build_lib))


class SdistWithCommit(sdist):
    def make_release_tree(self, base_dir, files):
        super().make_release_tree(base_dir, files)
        _write_commit(Path(base_dir))


setup(cmdclass={"build_py": BuildPyWithCommit, "sdist": SdistWithCommit})
