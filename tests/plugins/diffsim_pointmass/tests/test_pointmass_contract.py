"""This package's own tests: the diffsim-bench contract suite on its adapter, through the import."""

import pytest

import backends

if "pointmass" not in backends.available():  # only needed here: this file sits inside diffsim-bench's tree
    pytest.skip("diffsim-pointmass is not installed (tox -e py installs it)", allow_module_level=True)

from harness.contract_suite import ContractSuite  # noqa: E402


class TestPointMassContract(ContractSuite):
    backend_names = ("pointmass",)
