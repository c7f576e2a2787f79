"""The page's advice on a controller: every problem found without running it, each with its line.

The page's **Check** button shows these, one ``line N: what is wrong`` each,
and marks the lines in the editor. It extends :func:`common.controller.upload_gate.precheck`
(size, UTF-8, syntax, a Controller subclass), which the agent context and the
runner still run on every upload: this check is advice for the student, not a
gate, so it may be stricter (a misspelt robot call is legal Python) without
refusing anything the lab would run.

What it finds:

- a syntax error (the parser stops there, so only that one);
- no class deriving from ``Controller``, or one without ``do_work``;
- a call on the robot that :class:`common.controller.Khepera` does not have
  (``robot.set_speed(...)``; "did you mean set_speeds?"), or, given the chosen
  robot's components (:class:`common.controller.robot.RobotApi`), a call its
  components do not give ("this robot (epuck) has no gripper"; a sensor of its
  robot file, ``robot.floor()``, is a call it has). The robot is the
  second parameter of ``initialize``/``do_work``/``cleanup`` (whatever its
  name), any parameter annotated ``Khepera``, and ``self.<attr>`` assigned
  from one of those;
- an import the sandbox cannot satisfy or refuses (see :data:`FORBIDDEN` and
  docs/ARCHITECTURE.md, "Uploaded code"): the child is ``python3 -I -S`` with
  the standard library and common/controller/ only, in namespaces with no
  network, under a seccomp filter that refuses every socket family but
  AF_UNIX.

Standard library only: the viewer, the context and tests import it.
"""

from __future__ import annotations

import ast
import difflib
import sys
from dataclasses import dataclass

from common.controller import Khepera
from common.controller.robot import RobotApi
from common.controller.upload_gate import PrecheckError, controller_classes, precheck

# The public names of the robot's API: what a controller may call on it.
ROBOT_API = frozenset(name for name in dir(Khepera) if not name.startswith("_"))
ROBOT_METHODS = ("initialize", "do_work", "cleanup")

# Modules the sandbox refuses or cannot offer, and why (the student reads the why).
_NO_NETWORK = "the sandbox has no network"
_NO_PROCESSES = "a controller may not start processes"
FORBIDDEN: dict[str, str] = {
    **{
        m: _NO_NETWORK
        for m in (
            "socket",
            "ssl",
            "http",
            "urllib",
            "ftplib",
            "smtplib",
            "poplib",
            "imaplib",
            "telnetlib",
            "xmlrpc",
            "socketserver",
        )
    },
    **{m: _NO_PROCESSES for m in ("subprocess", "multiprocessing", "pty")},
    "ctypes": "native code is refused in the sandbox",
    "importlib": "a controller imports its modules by name, at the top",
}
# Of the lab's own package only the controller package is copied into the sandbox (whole:
# services/runner/stage.py), so its modules import there too.
ALLOWED_LAB_MODULES = frozenset({"common", "common.controller"})


@dataclass(frozen=True, order=True)
class Problem:
    """One thing wrong with a controller; ``line`` is 1-based, None for the whole file."""

    line: int | None
    message: str

    def __str__(self) -> str:
        return self.message if self.line is None else f"line {self.line}: {self.message}"


def check_source(
    source: bytes, filename: str = "controller.py", robot: RobotApi | None = None
) -> list[Problem]:
    """Every problem found in ``source`` (empty: it looks runnable), sorted by line.

    ``robot``: the chosen robot's components; the robot's calls are checked
    against them (None: against the Khepera's API).
    """
    try:
        text = source.decode("utf-8")
    except UnicodeDecodeError as exc:
        return [Problem(None, f"{filename} is not UTF-8 text (byte {exc.start})")]
    try:
        tree = ast.parse(text, filename=filename)
    except SyntaxError as exc:
        return [Problem(exc.lineno or 1, f"syntax error: {exc.msg}")]
    problems = []
    try:
        precheck(source, filename)
    except PrecheckError as exc:
        # Syntax is done above, with the line: what is left (size, no Controller) is the file's.
        problems.append(Problem(None, str(exc)))
    problems += _imports(tree)
    for cls in controller_classes(tree):
        problems += _check_class(cls, robot)
    return sorted(set(problems), key=lambda p: (p.line or 0, p.message))


def _module_problem(name: str, line: int) -> Problem | None:
    top = name.split(".")[0]
    if top in FORBIDDEN:
        return Problem(line, f"import {name} is not allowed: {FORBIDDEN[top]}")
    if top == "common":
        if name not in ALLOWED_LAB_MODULES and not name.startswith("common.controller."):
            return Problem(
                line,
                f"import {name} is not available in the sandbox: of the lab's code only "
                "common.controller is",
            )
        return None
    if top not in sys.stdlib_module_names:
        return Problem(
            line,
            f"import {name} is not available in the sandbox: it has Python's standard "
            "library and common.controller only",
        )
    return None


def _imports(tree: ast.Module) -> list[Problem]:
    problems = []
    for node in ast.walk(tree):
        names: list[str] = []
        line = getattr(node, "lineno", 1)
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # a relative import: the sandbox holds one file, no package
                problems.append(
                    Problem(node.lineno, "a relative import: a controller is a single file")
                )
                continue
            module = node.module or ""
            names = [module]
            if module == "common":  # from common import controller, files ...
                names = [f"common.{alias.name}" for alias in node.names]
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id == "__import__"
        ):
            first = node.args[0] if node.args else None
            if isinstance(first, ast.Constant) and isinstance(first.value, str):
                names = [first.value]
            else:
                problems.append(Problem(node.lineno, "__import__ of a computed name"))
        for name in names:
            problem = _module_problem(name, line)
            if problem is not None:
                problems.append(problem)
    return problems


def _robot_params(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> set[str]:
    """The names a method calls its robot by."""
    args = fn.args.posonlyargs + fn.args.args
    names = set()
    if fn.name in ROBOT_METHODS and len(args) >= 2:
        names.add(args[1].arg)
    for arg in args + fn.args.kwonlyargs:
        note = arg.annotation
        if note is not None:
            text = ast.unparse(note).strip("'\"")
            if text.split(".")[-1] == "Khepera":
                names.add(arg.arg)
    return names


def _check_call(what: str, attr: str, robot: RobotApi | None) -> str | None:
    """What is wrong with ``what.attr`` on this robot, or None."""
    api = ROBOT_API if robot is None else robot.calls()
    if attr in api:
        return None
    if robot is not None:
        missing = robot.missing(attr)
        if missing:
            return f"{what}.{attr}: {missing}"
    close = difflib.get_close_matches(attr, sorted(api), n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    name = "Khepera" if robot is None else f"this robot ({robot.type_name})"
    return f"{what}.{attr} does not exist on {name}{hint}"


def _check_class(cls: ast.ClassDef, robot: RobotApi | None = None) -> list[Problem]:
    methods = [n for n in cls.body if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]
    problems = []
    if not any(m.name == "do_work" for m in methods):
        problems.append(Problem(cls.lineno, f"class {cls.name} has no do_work(self, robot) method"))
    # self.<attr> = robot in any method makes self.<attr> the robot everywhere in the class.
    robot_attrs: set[str] = set()
    for fn in methods:
        params = _robot_params(fn)
        for node in ast.walk(fn):
            if (
                isinstance(node, ast.Assign)
                and isinstance(node.value, ast.Name)
                and node.value.id in params
            ):
                for target in node.targets:
                    if (
                        isinstance(target, ast.Attribute)
                        and isinstance(target.value, ast.Name)
                        and target.value.id == "self"
                    ):
                        robot_attrs.add(target.attr)
    for fn in methods:
        params = _robot_params(fn)
        for node in ast.walk(fn):
            if not isinstance(node, ast.Attribute):
                continue
            owner = node.value
            if isinstance(owner, ast.Name) and owner.id in params:
                what = owner.id
            elif (
                isinstance(owner, ast.Attribute)
                and isinstance(owner.value, ast.Name)
                and owner.value.id == "self"
                and owner.attr in robot_attrs
            ):
                what = f"self.{owner.attr}"
            else:
                continue
            message = _check_call(what, node.attr, robot)
            if message is not None:
                problems.append(Problem(node.lineno, message))
    return problems
