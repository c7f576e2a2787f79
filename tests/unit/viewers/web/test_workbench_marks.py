"""The editor marks lines: Check's problems, and a run's exception found in relayed output."""

from __future__ import annotations

from common.controller.advice import Problem
from viewers.web.adapters import DryRunResult
from viewers.web.marks import TracebackReader, excerpt, format_dry_run, format_problems

TRACEBACK = [
    "Traceback (most recent call last):",
    '  File "/sandbox/lib/common/controller/__init__.py", line 320, in run',
    "    self.controller.do_work(self.robot)",
    '  File "/work/user/controller.py", line 12, in do_work',
    "    x = 1 / 0",
    "ZeroDivisionError: division by zero",
]


def test_the_exception_is_placed_at_the_students_line_not_the_apis() -> None:
    reader = TracebackReader("circle.py")
    found = [p for p in (reader.feed(line) for line in TRACEBACK) if p is not None]
    assert [str(p) for p in found] == ["line 12: ZeroDivisionError: division by zero"]


def test_plain_prints_are_not_errors() -> None:
    reader = TracebackReader()
    assert reader.feed("hello") is None and reader.feed("ValueError is a word here") is None


def test_the_excerpt_marks_each_problem_line() -> None:
    source = "a = 1\nb = 2\nc = 3\nd = 4\ne = 5\n"
    text = excerpt(source, [Problem(2, "x"), Problem(5, "y"), Problem(None, "file")])
    assert ">> 2 | b = 2" in text and ">> 5 | e = 5" in text and "   3 | c = 3" in text


def test_a_dry_runs_exception_is_marked_at_its_line_and_said_once() -> None:
    source = "a = 1\nb = 1 / 0\nc = 3\n"
    verdict = "will NOT run: line 2: ZeroDivisionError: division by zero"
    result = DryRunResult(False, verdict, ("| hello",), line=2)
    text = format_dry_run(source, result, f"Dry run of x.py on k0: {verdict}")
    assert "&gt;&gt; 2 | b = 1 / 0" in text
    # The item links its line to the editor and says it once (not "line 2: ... line 2").
    assert ">line 2</a>: ZeroDivisionError: division by zero</li>" in text
    assert 'data-wart-line="2"' in text
    assert text.count("line 2:") == 1  # the heading; the item's "line 2" is the link
    assert text.endswith('<pre class="wart-output">| hello</pre>')  # printed lines, verbatim


def test_a_dry_runs_collision_has_no_line_to_mark() -> None:
    verdict = "will run, with a warning: 1 collision, the first with a wall at 0.84 s"
    result = DryRunResult(True, verdict, ("collision at 0.84 s: wall",))
    text = format_dry_run("x = 1\n", result, f"Dry run on k3: {verdict}")
    assert "&gt;&gt;" not in text and "the first with a wall" in text
    assert "collision at 0.84 s: wall" in text  # as said, not escaped for markdown


def test_problems_are_escaped_html_never_interpreted() -> None:
    text = format_problems("x = '<b>'\n", [Problem(1, "*not* <b>bold</b> #1")], "Check: 1 [a]")
    assert "<b>bold</b>" not in text and "&lt;b&gt;bold&lt;/b&gt;" in text
    assert "*not*" in text and "#1" in text and "\\" not in text
    assert "x = &#x27;&lt;b&gt;&#x27;" in text
