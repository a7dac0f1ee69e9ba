"""docs/extending.md, tested against the template it points to: the adapter block in the docs is the
point-mass plug-in's adapter, word for word, and the class that block defines, built exactly as the
docs write it, passes the contract suite."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import backends

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "extending.md"
TEMPLATE = ROOT / "tests" / "plugins" / "diffsim_pointmass" / "diffsim_pointmass" / "__init__.py"

if "pointmass" not in backends.available():
    pytest.skip("the point-mass plug-in is absent (tox -e py installs it)", allow_module_level=True)

from harness.contract_suite import ContractSuite  # noqa: E402


def _documented_block() -> str:
    match = re.search(r"<!-- template-adapter -->\n```python\n(.*?)\n```", DOCS.read_text(), re.S)
    assert match, "docs/extending.md lost its template block"
    return match.group(1)


def _documented_adapter() -> type:
    """The adapter class the docs' block defines, run as a user would paste it."""
    namespace: dict = {"__name__": "documented_adapter"}
    exec(compile(_documented_block(), "docs/extending.md", "exec"), namespace)
    return namespace["PointMassSim"]


def test_the_documented_adapter_is_the_templates_word_for_word():
    source = TEMPLATE.read_text()
    (cls,) = [n for n in ast.parse(source).body if isinstance(n, ast.ClassDef) and n.name == "PointMassSim"]
    assert ast.get_source_segment(source, cls) in _documented_block()


def test_the_docs_name_every_hook_the_base_class_requires():
    """Every abstract method of the contract appears in the docs' numbered steps, and the template
    overrides nothing the docs do not describe."""
    from backends.contract import BatchedSim

    text = DOCS.read_text()
    for name in BatchedSim.__abstractmethods__:
        assert f"`{name}" in text, name
    documented = set(re.findall(r"`(_?[a-z_]+)\(", text)) | set(re.findall(r"`([a-z_]+)`", text))
    own = {n for n in vars(_documented_adapter()) if not n.startswith("__") and n != "_abc_impl"}
    assert own - documented - {"mass"} == set(), own - documented  # mass: the point's own constant


class TestTheAdapterTheDocsWrite(ContractSuite):
    adapter_classes = {"documented": _documented_adapter()}
    backend_names = ("documented",)
