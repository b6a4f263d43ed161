"""Docs stay true to the code: the scene-key reference in docs/USAGE.md is the generated one."""
import importlib.util

import pytest

from conftest import ROOT

pytestmark = pytest.mark.fast  # make check runs this whole module


def test_usage_key_reference_is_up_to_date():
    spec = importlib.util.spec_from_file_location("update_docs", ROOT / "scripts" / "update_docs.py")
    update_docs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(update_docs)
    text = update_docs.USAGE.read_text()
    assert update_docs.rendered(text) == text, "run: .venv/bin/python scripts/update_docs.py"
