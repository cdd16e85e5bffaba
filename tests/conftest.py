"""Fixtures shared by every test folder. The helper modules beside this file
(``synthetic_scenes``, ``posed_data``, ``factories``, ``addon_support``, ...) are importable from
every folder: pyproject's ``pythonpath`` puts ``tests/`` on ``sys.path``."""

from __future__ import annotations

import os

import pytest
import torch


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist (``make test`` runs ``-n auto``) each worker gets its share of the
    cores, so N workers do not each start a thread per core and fight over them."""
    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if workers:
        torch.set_num_threads(max(1, (os.cpu_count() or 1) // int(workers)))


@pytest.fixture(autouse=True)
def _restore_thread_count():
    """Whatever a test (or code it runs: training sets torch's thread count) does to the
    thread count is undone after it, so no test's speed depends on the one before."""
    before = torch.get_num_threads()
    yield
    if torch.get_num_threads() != before:
        torch.set_num_threads(before)


@pytest.fixture(scope="module")
def one_thread():
    """Torch on one thread for a module of tiny tensors: with 2 threads on a shared 2-core
    machine the parallel regions' overhead made such files up to 10x slower."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def shipped_model():
    """The shipped generator and improvement model (``ProSplat.from_pretrained()``), loaded
    once per test module; tests must not change it."""
    from prosplat import ProSplat

    return ProSplat.from_pretrained()


@pytest.fixture(scope="module")
def shipped_generator():
    """The shipped generator alone (``ProSplat.from_pretrained(improve=False)``), loaded once
    per test module; tests must not change it."""
    from prosplat import ProSplat

    return ProSplat.from_pretrained(improve=False)
