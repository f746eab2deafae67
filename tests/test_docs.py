"""The docs' Python examples run as written (so they cannot rot)."""

from __future__ import annotations

import os
import re

import pytest
from helpers import REPO

import nodes  # noqa: F401  (register the drone leaves before any registry snapshot)

DOCS = ["engine.md", "testing-missions.md"]


@pytest.mark.parametrize("doc", DOCS)
def test_python_examples_in_docs_run(doc, monkeypatch):
    from bt_engine.registry import REGISTRY

    monkeypatch.chdir(REPO)
    saved = (dict(REGISTRY._models), dict(REGISTRY._aliases))
    text = open(os.path.join(REPO, "docs", doc), encoding="utf-8").read()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks
    ns: dict = {}
    try:
        for block in blocks:
            exec(compile(block, doc, "exec"), ns)  # noqa: S102 - our own documentation
    finally:
        REGISTRY._models, REGISTRY._aliases = saved


def test_readme_python_example_runs(monkeypatch):
    monkeypatch.chdir(REPO)
    text = open(os.path.join(REPO, "README.md"), encoding="utf-8").read()
    (block,) = re.findall(r"```python\n(.*?)```", text, re.S)
    exec(compile(block.replace("print(", "(lambda *a: None)("), "README.md", "exec"), {})  # noqa: S102
