"""TOML people hand in: nesting counted before tomllib, brackets in strings and comments
not counted."""

from __future__ import annotations

import tomllib

import pytest

from common.handed_in import load_toml, nesting_depth


def test_nesting_is_counted_outside_strings_and_comments_and_a_deep_file_refused() -> None:
    text = "a = [[1, 2], {b = \"[[[[{{\"}]  # ]]]] [[[[\nc = '''[[[\n[[['''\n[t]\n"
    assert nesting_depth(text) == 2
    assert load_toml(text)["a"] == [[1, 2], {"b": "[[[[{{"}]
    with pytest.raises(tomllib.TOMLDecodeError, match="nested more than 64 deep"):
        load_toml("deep = " + "[" * 5000 + "]" * 5000)  # never reaches tomllib's recursion
    load_toml("ok = " + "[" * 64 + "]" * 64)
