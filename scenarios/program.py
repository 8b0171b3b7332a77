"""Your own Kilobot program on every robot: ``kilonet run --program my_bot.py[:ClassName]``.

The file is loaded as a module (its folder goes on ``sys.path``, as for a script, so it can
import its neighbours) and the class to run is the one Kilobot subclass it defines, or the one
named after the colon. Every robot runs ``ClassName()``; the swarm comes from ``--placement``
or ``--robots`` (a jittered hex lattice), and the run writes what every scenario writes
(``robots.csv``, ``led.csv``, ``events.csv``, ``poses.csv``, ``summary.json``,
``params.json``) plus ``program.png``: start and final positions, LEDs and paths, and
``program.py``, a copy of the source whose SHA-256 the summary gives (``program_sha256``).

A run file's ``[program]`` section, and ``--set program.NAME=VALUE``, set class attributes
the program declares (``gain = 0.5`` in its class body) on every robot before ``setup()``
(:func:`program_settings`): a program's own parameters, the parameter section ``program``
(:func:`settings_section`), checked, recorded in ``params.json`` and the summary and listed by
``kilonet params --program FILE.py`` like kilonet's. What a class's ``report()`` returns
becomes columns of ``robots.csv`` and, summed up, the summary's ``report``
(:func:`aggregate_reports`). A sweep names a program by :func:`program_key`, which
:func:`kilonet.scenarios.get` loads in whichever process runs the run.

A program that cannot run is refused in one line naming the file and line
(:class:`ProgramError`): a missing file, a syntax error, an exception while the file loads,
no Kilobot subclass (or a name that is not one, or one whose constructor needs arguments), a
write of a kernel name (``self._krate = ...``), what the kernel refuses of the class (a
callback it cannot call, a redefined kilolib function; :func:`kilonet.robot.check_program_class`)
or of a run (a yield of anything but a delay, a bad ``position_estimate``), an exception raised
by the program while the swarm runs (in ``setup``, ``loop``, ``message_rx``, ...; any
``BaseException`` but Ctrl-C, ``sys.exit()`` included):
``my_bot.py:14: in setup: ZeroDivisionError: division by zero (robot 2)``, and a thread of the
program left running.
"""

from __future__ import annotations

import ast
import dataclasses
import hashlib
import importlib.util
import inspect
import math
import sys
import threading
import weakref
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kilonet.errors import ProgramFault, exception_line, read_text
from kilonet.message import PayloadError
from kilonet.robot import RESERVED_PREFIX, Kilobot
from kilonet.scenarios.base import Drawing, Reporting, RunResult, Scenario, ScenarioError, Setup
from kilonet.watchdog import BusyCallError

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = [
    "PROGRAM_PREFIX",
    "ProgramError",
    "aggregate_reports",
    "declared_settings",
    "load_program",
    "parse_spec",
    "program_key",
    "program_scenario",
    "program_settings",
    "reported_as_user_errors",
    "scenario_of_key",
    "settings_section",
]


class ProgramError(ScenarioError):
    """A user's program file cannot be run; the message names the file and line."""


def parse_spec(spec: str) -> tuple[Path, str | None]:
    """The file and class name of ``FILE.py[:ClassName]``.

    Examples
    --------
    >>> parse_spec("bots/orbit.py:Planet")
    (PosixPath('bots/orbit.py'), 'Planet')
    >>> parse_spec("orbit.py")
    (PosixPath('orbit.py'), None)
    """
    head, sep, tail = spec.rpartition(":")
    if sep and tail.isidentifier() and head:
        return Path(head), tail
    return Path(spec), None


def _class_lines(source: str) -> dict[str, int]:
    return {
        node.name: node.lineno
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.ClassDef)
    }


def load_program(spec: str) -> tuple[Path, type[Kilobot]]:
    """The program file and Kilobot subclass that ``spec`` (``FILE.py[:ClassName]``) names.

    Raises
    ------
    ProgramError
        If the file is missing or unreadable, does not compile, raises while it loads, defines
        no Kilobot subclass (or several, and none is named), the named class is missing or not
        a Kilobot subclass, or its constructor needs arguments.
    """
    path, name = parse_spec(spec)
    source = read_text(path, ProgramError, "program file")
    if path.suffix != ".py":
        raise ProgramError(
            f"{path}: a program is a Python file (--program FILE.py[:CLASS]); a run file "
            f"(.toml) goes first: kilonet run RUN.toml --program FILE.py"
        )
    try:
        compile(source, str(path), "exec")
    except SyntaxError as exc:
        raise ProgramError(f"{path}:{exc.lineno}: syntax error: {exc.msg}") from None
    module_name = f"kilonet_program_{abs(hash(str(path.resolve())))}"
    loader_spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(loader_spec)
    sys.modules[module_name] = module
    folder = str(path.resolve().parent)
    if folder not in sys.path:
        sys.path.insert(0, folder)
    with reported_as_user_errors(path, "while loading"):
        loader_spec.loader.exec_module(module)
    lines = _class_lines(source)
    if name is None:
        defined = [
            c
            for c in vars(module).values()
            if inspect.isclass(c) and issubclass(c, Kilobot) and c.__module__ == module_name
        ]
        if not defined:
            raise ProgramError(
                f"{path}: defines no Kilobot subclass (class MyBot(Kilobot): ... with setup, "
                "loop, message_tx, message_rx)"
            )
        if len(defined) > 1:
            names = ", ".join(c.__name__ for c in defined)
            # Suggest a class no other one builds on: the one that combines the others
            # (orbit.py's Orbit runs OrbitStar and OrbitPlanet), else the first.
            leaves = [
                c for c in defined if not any(d is not c and issubclass(d, c) for d in defined)
            ]
            suggested = leaves[0] if len(leaves) == 1 else defined[0]
            raise ProgramError(
                f"{path}: defines several Kilobot subclasses ({names}); name one: "
                f"--program {path}:{suggested.__name__}"
            )
        (cls,) = defined
    else:
        cls = getattr(module, name, None)
        where = f"{path}:{lines[name]}" if name in lines else str(path)
        if cls is None:
            raise ProgramError(f"{path}: has no {name!r}")
        if not (inspect.isclass(cls) and issubclass(cls, Kilobot)) or cls is Kilobot:
            raise ProgramError(f"{where}: {name} is not a Kilobot subclass")
    required = [
        p.name
        for p in inspect.signature(cls).parameters.values()
        if p.default is p.empty and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
    ]
    if required:
        where = f"{path}:{lines[cls.__name__]}" if cls.__name__ in lines else str(path)
        raise ProgramError(
            f"{where}: {cls.__name__}() needs {', '.join(required)}; every robot runs "
            f"{cls.__name__}() with no arguments"
        )
    _refuse_kernel_writes(path, source, cls)
    return path, cls


def _refuse_kernel_writes(path: Path, source: str, cls: type[Kilobot]) -> None:
    """Refuse a program whose classes in ``source`` write a kernel name on the robot
    (``self._krate = 0.0``, ``setattr(self, "_krate", ...)``, ``del self._kenv``) anywhere,
    before it runs: written in ``loop`` it would change what the kernel counts without a word
    (a write the source does not spell out is found when the run stops)."""
    mine = {k.__name__ for k in cls.__mro__ if k.__module__ == cls.__module__}
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.ClassDef) and node.name in mine):
            continue
        for method in node.body:
            if not isinstance(method, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for inner in ast.walk(method):
                name = _kernel_write(inner)
                if name is not None:
                    raise ProgramError(
                        f"{path}:{inner.lineno}: {node.name}.{method.name} sets self.{name}: "
                        f"names starting with {RESERVED_PREFIX!r} are the kernel's; rename it"
                    )


def _kernel_write(node: ast.AST) -> str | None:
    """The kernel name that statement ``node`` writes on ``self``, if it writes one."""
    targets: list[ast.expr] = []
    if isinstance(node, ast.Assign | ast.Delete):
        targets = node.targets
    elif isinstance(node, ast.AugAssign | ast.AnnAssign):
        targets = [node.target]
    elif (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id in ("setattr", "delattr")
        and len(node.args) >= 2
        and isinstance(node.args[0], ast.Name)
        and node.args[0].id == "self"
        and isinstance(node.args[1], ast.Constant)
        and isinstance(node.args[1].value, str)
        and node.args[1].value.startswith(RESERVED_PREFIX)
    ):
        return node.args[1].value
    for target in targets:
        for leaf in ast.walk(target):
            if (
                isinstance(leaf, ast.Attribute)
                and isinstance(leaf.value, ast.Name)
                and leaf.value.id == "self"
                and leaf.attr.startswith(RESERVED_PREFIX)
            ):
                return leaf.attr
    return None


@contextmanager
def reported_as_user_errors(path: str | Path, during: str = "") -> Iterator[None]:
    """Turn an exception raised in the program, the file ``path`` or a module beside it
    (which it imports: its folder is on ``sys.path``), into a one-line :class:`ProgramError`
    naming the file, the line, the function and the robot
    (``my_bot.py:14: in setup: ZeroDivisionError: division by zero (robot 2)``), and a
    :class:`~kilonet.errors.ProgramFault` the kernel raised about the program into one naming
    the file as the user wrote it. Anything derived from ``BaseException`` counts
    (``sys.exit()``, ``raise GeneratorExit``) but ``KeyboardInterrupt`` (the user's Ctrl-C);
    exceptions that did not pass through the program are left alone (they are kilonet's).

    A thread of the program still running (not a daemon) when the block ends is refused too:
    the interpreter would wait for it at exit, forever.
    """
    program = _ProgramFiles(Path(path))
    before = {t.ident for t in threading.enumerate()}
    try:
        yield
    except (ScenarioError, BusyCallError, KeyboardInterrupt):
        raise
    except ProgramFault as fault:
        shown = program.named(fault.file) if fault.file is not None else None
        if shown is not None:
            raise ProgramError(f"{shown}:{fault.line}: {fault.message}") from None
        raise ProgramError(str(fault)) from None
    except PayloadError as exc:
        found = program.frame(exc)
        if found is not None:
            shown, frame, line, _ = found
            raise ProgramError(f"{shown}:{line}: in {frame.f_code.co_name}: {exc}") from None
        raise ProgramError(f"{path}: {exc}") from None  # what message_tx returned
    except BaseException as exc:
        found = program.frame(exc)
        if found is None:
            raise
        shown, frame, line, error = found
        name = frame.f_code.co_name
        context = f"in {name}" if name != "<module>" else (during or "at top level")
        robot = _robot_of(error)
        note = f" (robot {robot._kindex})" if robot is not None else ""
        if isinstance(error, SystemExit):
            back = "; return from the callback" if name != "<module>" else ""
            note = f" (a robot program cannot end kilonet{back})"
        raise ProgramError(f"{shown}:{line}: {context}: {exception_line(exc)}{note}") from None
    program.refuse_threads_left(before)


class _ProgramFiles:
    """The files of a program: its file ``path`` (as the user named it) and the Python
    modules beside it, which it may import."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.target = path.resolve()

    def named(self, filename: str) -> Path | None:
        """``filename`` as the user would name it, if it is a file of the program."""
        file = Path(filename).resolve()
        if file == self.target:
            return self.path
        if file.parent == self.target.parent and file.suffix == ".py":
            return self.path.parent / file.name
        return None

    def frame(self, exc: BaseException) -> tuple[Path, Any, int, BaseException] | None:
        """The innermost frame of the program that ``exc`` passed through: its file as the
        user names it, the frame, its line, and the exception it passed as: ``exc`` or, for
        the copy of a failed process's exception that the kernel raises, the original (the
        first ``__cause__`` with a frame of the program)."""
        error: BaseException | None = exc
        while error is not None:
            found = None
            tb = error.__traceback__
            while tb is not None:
                shown = self.named(tb.tb_frame.f_code.co_filename)
                if shown is not None:
                    found = (shown, tb.tb_frame, tb.tb_lineno, error)
                tb = tb.tb_next
            if found is not None:
                return found
            error = error.__cause__
        return None

    def refuse_threads_left(self, before: set[int | None]) -> None:
        """Refuse a thread the program started, not a daemon, that still runs (see
        :func:`reported_as_user_errors`), naming the line of the program it runs now."""
        frames = sys._current_frames()
        for thread in threading.enumerate():
            if thread.daemon or thread.ident in before or not thread.is_alive():
                continue
            frame = frames.get(thread.ident)
            while frame is not None and self.named(frame.f_code.co_filename) is None:
                frame = frame.f_back
            if frame is not None:
                raise ProgramError(
                    f"{self.named(frame.f_code.co_filename)}:{frame.f_lineno}: the program's "
                    f"thread {thread.name!r} still runs after the run, and kilonet would wait "
                    "for it forever; start it with daemon=True, or end it"
                )


def _robot_of(error: BaseException) -> Kilobot | None:
    """The robot whose program ``error`` passed through (the ``self`` of its innermost robot
    method on the traceback), if any."""
    robot = None
    tb = error.__traceback__
    while tb is not None:
        candidate = tb.tb_frame.f_locals.get("self")
        if isinstance(candidate, Kilobot) and isinstance(getattr(candidate, "_kindex", None), int):
            robot = candidate
        tb = tb.tb_next
    return robot


#: Types a ``[program]`` setting may have: those of the class attribute it replaces.
_SETTING_TYPES = (bool, int, float, str)


def declared_settings(cls: type[Kilobot]) -> dict[str, Any]:
    """The settings a program declares, each with its default: every public class attribute of
    ``cls`` and of its bases below :class:`~kilonet.robot.Kilobot` holding a bool, int, finite
    float or str (``patience_ticks = 31`` in the class body), in declaration order, bases first.
    A float that is not finite (``math.inf``) is not a setting: a parameter must be finite.

    Examples
    --------
    >>> class Bot(Kilobot):
    ...     speed = 2.5
    ...     name = "a"
    ...     _hidden = 1
    ...     limits = (1, 2)
    >>> declared_settings(Bot)
    {'speed': 2.5, 'name': 'a'}
    """
    out: dict[str, Any] = {}
    for klass in reversed(cls.__mro__[: cls.__mro__.index(Kilobot)]):
        for name, value in vars(klass).items():
            if name.startswith("_"):
                continue
            usable = isinstance(value, _SETTING_TYPES) and not (
                isinstance(value, float) and not math.isfinite(value)
            )
            if usable:
                out[name] = value
            else:
                out.pop(name, None)  # a subclass turned it into something else
    return out


def settings_section(cls: type[Kilobot], source: str) -> type:
    """The program's settings as a parameter section named ``program``: a frozen dataclass with
    one field per :func:`declared_settings` entry, of its default's type, so that
    :class:`~kilonet.params.Params` checks, records (``params.json``) and lists
    (``kilonet params --program``) them like kilonet's own keys. ``source`` names the file in
    each field's description and in an error.

    Raises
    ------
    ProgramError
        If the program declares ``section_name``, the attribute that names a section.
    """
    if "section_name" in declared_settings(cls):
        raise ProgramError(
            f"{source}: {cls.__name__}.section_name: kilonet names a parameter section with "
            "this attribute, so a program's setting cannot have this name; rename it"
        )
    fields = [
        (
            name,
            type(default),
            dataclasses.field(
                default=default,
                metadata={"doc": f"{cls.__name__}.{name} in {Path(source).name}"},
            ),
        )
        for name, default in declared_settings(cls).items()
    ]
    return dataclasses.make_dataclass(
        f"{cls.__name__}Settings", fields, frozen=True, namespace={"section_name": "program"}
    )


def program_settings(
    cls: type[Kilobot], settings: dict[str, Any], where: Callable[[str], str] = str
) -> dict[str, Any]:
    """The values a run file's ``[program]`` section (or ``--set program.NAME=VALUE``) gives
    the program's class attributes, checked and converted: each name must be a class
    attribute the program declares (``speed = 3`` in its class body) holding a bool, int,
    float or str, and each value must be of that type (an int for a float; text from
    ``--set`` is converted).

    ``where(name)`` says where a setting came from, for the error (``run.toml:7``).

    Raises
    ------
    ProgramError
        For a name the class does not declare, or a value of another type.

    Examples
    --------
    >>> class Bot(Kilobot):
    ...     speed = 2.5
    ...     verbose = False
    >>> program_settings(Bot, {"speed": 3, "verbose": "true"})
    {'speed': 3.0, 'verbose': True}
    """
    declared = declared_settings(cls)
    out: dict[str, Any] = {}
    for name, value in settings.items():
        default = declared.get(name)
        if default is None:
            raise ProgramError(
                f"{where(name)}: program.{name}: {cls.__name__} has no class attribute {name!r} "
                f"holding a number, bool or text; a [program] key sets one the class declares "
                f"({name} = ... in the class body)"
            )
        out[name] = _converted(value, type(default), f"{where(name)}: program.{name}")
    return out


def _converted(value: Any, kind: type, where: str) -> Any:
    if isinstance(value, str) and kind is not str:
        text = value.strip().lower()
        if kind is bool and text in ("true", "false"):
            return text == "true"
        try:
            return kind(text) if kind is not bool else _refuse(value, kind, where)
        except ValueError:
            _refuse(value, kind, where)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if type(value) is not kind:
        _refuse(value, kind, where)
    return value


def _refuse(value: Any, kind: type, where: str) -> Any:
    article = "an" if kind is int else "a"
    raise ProgramError(
        f"{where} = {value!r} is not {article} {kind.__name__}, as the class's default is"
    )


def program_scenario(
    spec: str,
    settings: dict[str, Any] | None = None,
    where: Callable[[str], str] = str,
    *,
    sha256: str | None = None,
) -> Scenario:
    """A scenario that runs the program ``spec`` (``FILE.py[:ClassName]``) on every robot.

    The program's declared settings (:func:`declared_settings`) are the scenario's parameter
    section ``program`` (:func:`settings_section`): ``program.NAME`` keys of a run's overrides
    or of a sweep set them, and every robot's program gets them as attributes before its
    ``setup()`` (those that differ from the class's value). ``settings`` (checked by
    :func:`program_settings`; ``where(name)`` says where one came from, for an error) become
    the section's defaults, as a run file's ``[program]`` does.

    The summary names the program (``program``: ``FILE.py:ClassName``), the SHA-256 of its
    source (``program_sha256``) and its settings (``program_settings``). A class defining
    ``report(self) -> dict`` has each robot's values as columns of ``robots.csv`` and, summed
    up over the robots (:func:`aggregate_reports`), under ``report`` in the summary. A run
    directory holds a copy of the source as ``program.py`` and ``program.png``.

    Raises
    ------
    ProgramError
        If the program cannot be loaded (:func:`load_program`), a setting is refused, or its
        source's SHA-256 is not ``sha256`` (when given: the file changed since a sweep named it).
    """
    path, cls = load_program(spec)
    source = path.read_bytes()
    digest = hashlib.sha256(source).hexdigest()
    if sha256 is not None and digest != sha256:
        raise ProgramError(
            f"{path}: changed since the sweep was defined (sha256 {digest[:12]}..., the "
            f"sweep's {sha256[:12]}...); run the sweep again into a new --out directory"
        )
    label = f"{path.name}:{cls.__name__}"
    values = program_settings(cls, dict(settings or {}), where)
    section = settings_section(cls, str(path))
    reporting = callable(getattr(cls, "report", None))

    declared = declared_settings(cls)

    def program(params: Any, positions: Any):
        # Only the settings that differ from the class's value become instance attributes: a
        # program that changes a class attribute while it runs (a shared count) reads it as
        # it would without kilonet's settings.
        chosen = {
            name: value
            for name, value in dataclasses.asdict(params.scenario).items()
            if value != declared[name]
        }

        def build(_i: int) -> Kilobot:
            robot = cls()
            for name, value in chosen.items():
                setattr(robot, name, value)
            return robot

        return build

    def metrics(sim: Simulation) -> dict[str, Any]:
        out = {
            "program": label,
            "program_sha256": digest,
            "program_settings": dataclasses.asdict(sim.params.scenario),
        }
        if reporting:
            out["report"] = aggregate_reports(_reports(sim, path))
        return out

    def robot_columns(sim: Simulation) -> Any:
        import pandas as pd

        rows = _reports(sim, path)
        taken = {"uid", *sim.robots_frame().columns}
        clash = sorted(taken.intersection(key for row in rows for key in row))
        if clash:
            raise ProgramError(
                f"{_where(cls, 'report', path)}: report() returns {clash[0]!r}, a column kilonet "
                "writes in robots.csv; give the value another name"
            )
        return pd.DataFrame(rows).assign(robot=range(len(rows)))

    def outputs(result: RunResult, out_dir: Path) -> None:
        (out_dir / "program.py").write_bytes(source)
        _figure(result, label, out_dir / "program.png")

    return Scenario(
        name="program",
        summary=f"your program {label} on every robot",
        setup=Setup(
            program=program,
            section=section,
            robots=0,
            defaults={f"program.{name}": value for name, value in values.items()},
        ),
        reporting=Reporting(
            metrics=metrics,
            robot_columns=robot_columns if reporting else None,
        ),
        drawing=Drawing(
            figures=outputs,
        ),
    )


#: Types a value of ``report()`` may have (numpy scalars are taken as their Python values).
_REPORT_TYPES = (bool, int, float, str, type(None))

#: Each finished simulation's ``report()`` rows, so the summary and robots.csv share one call.
_REPORTED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _reports(sim: Simulation, path: Path) -> list[dict[str, Any]]:
    """Every robot's ``report()``, checked: a dict of names to numbers, bools, text or None."""
    if sim in _REPORTED:
        return _REPORTED[sim]
    rows = []
    for robot in sim.robots:
        with reported_as_user_errors(path, "in report"):
            row = robot.report()
        where = _where(type(robot), "report", path)
        if not isinstance(row, dict):
            raise ProgramError(
                f"{where}: report() returned {type(row).__name__}; it returns a dict of "
                "names to values, one per robot"
            )
        for key, value in row.items():
            if hasattr(value, "item") and not isinstance(value, str):
                value = row[key] = value.item()  # a numpy scalar
            if not isinstance(key, str) or not isinstance(value, _REPORT_TYPES):
                raise ProgramError(
                    f"{where}: report() returned {key!r}: {value!r}; its keys are names and "
                    "its values numbers, bools, text or None"
                )
        rows.append(row)
    _REPORTED[sim] = rows
    return rows


def _where(cls: type, method: str, path: Path) -> str:
    """``path:LINE`` of ``cls.method`` (the program file ``path`` as the user named it), for an
    error about what it returned; just ``path`` when the method is defined elsewhere."""
    code = getattr(getattr(cls, method), "__code__", None)
    if code is None or Path(code.co_filename).resolve() != path.resolve():
        return str(path)
    return f"{path}:{code.co_firstlineno}"


def aggregate_reports(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Each reported value summed up over the robots: for a bool the robots where it is true
    and false; for a number its ``min``, ``mean`` and ``max``; for text the number of
    ``distinct`` values and the most common one (``most``, the first in sorted order on a tie).
    Every entry counts the robots that reported no value (``none``: key missing or None).

    Examples
    --------
    >>> aggregate_reports([{"leader": True, "max": 7, "state": "done"},
    ...                    {"leader": False, "max": 5, "state": "done"}])
    ... # doctest: +NORMALIZE_WHITESPACE
    {'leader': {'true': 1, 'false': 1, 'none': 0},
     'max': {'min': 5, 'mean': 6.0, 'max': 7, 'none': 0},
     'state': {'distinct': 1, 'most': 'done', 'none': 0}}
    """
    keys = list(dict.fromkeys(key for row in rows for key in row))
    out: dict[str, dict[str, Any]] = {}
    for key in keys:
        values = [row.get(key) for row in rows]
        given = [v for v in values if v is not None]
        missing = len(values) - len(given)
        if given and all(isinstance(v, bool) for v in given):
            true = sum(given)
            out[key] = {"true": true, "false": len(given) - true, "none": missing}
        elif given and all(isinstance(v, int | float) and not isinstance(v, bool) for v in given):
            mean = math.fsum(given) / len(given)
            out[key] = {"min": min(given), "mean": mean, "max": max(given), "none": missing}
        else:
            counts = Counter(str(v) for v in given)
            most = min(counts, key=lambda v: (-counts[v], v)) if counts else None
            out[key] = {"distinct": len(counts), "most": most, "none": missing}
    return out


#: How a sweep's scenario name for a program file begins (:func:`program_key`).
PROGRAM_PREFIX = "program:"


def program_key(spec: str, folder: str | Path = ".") -> str:
    """The scenario name a sweep stores for the program ``spec`` (``FILE.py[:ClassName]``,
    relative to ``folder``): ``program:/absolute/FILE.py:ClassName@SHA256``.
    :func:`kilonet.scenarios.get` turns it back into the scenario (:func:`scenario_of_key`), in
    whichever process runs the run, and refuses a file that changed since.

    Raises
    ------
    ProgramError
        If the program cannot be loaded (:func:`load_program`).
    """
    path, name = parse_spec(spec)
    path = Path(folder) / path
    _, cls = load_program(f"{path}:{name}" if name else str(path))
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return f"{PROGRAM_PREFIX}{path.resolve()}:{cls.__name__}@{digest}"


def scenario_of_key(key: str) -> Scenario:
    """The scenario of a :func:`program_key` name: the file loaded by its path, checked against
    the SHA-256 the key holds.

    Raises
    ------
    ProgramError
        If the key is malformed, or the program cannot be loaded or changed.
    """
    spec, sep, digest = key.removeprefix(PROGRAM_PREFIX).rpartition("@")
    if not (key.startswith(PROGRAM_PREFIX) and sep and spec):
        raise ProgramError(
            f"{key!r} is not a program's scenario name (program:FILE.py:CLASS@SHA256)"
        )
    return program_scenario(spec, sha256=digest)


def _figure(result: RunResult, label: str, path: Path) -> None:
    """Start positions (open circles), paths and final positions filled with the LED colour."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.patches import Circle

    sim = result.sim
    start, end = sim.initial_positions_mm, sim.world.positions_mm
    radius = sim.world.radius_mm
    poses = sim.trace.poses_frame()
    fig, ax = plt.subplots(figsize=(6, 6))
    for robot, path_xy in poses.groupby("robot")[["x_mm", "y_mm"]]:
        xy = np.vstack([start[robot], path_xy.to_numpy()])
        ax.plot(xy[:, 0], xy[:, 1], color="0.3", lw=0.8, zorder=3)
    for k, (x, y) in enumerate(start):
        ax.add_patch(Circle((x, y), radius, fc="none", ec="0.7", ls="--"))
        colour = np.array(sim.robots[k].color, dtype=float) / 3.0
        ax.add_patch(Circle(tuple(end[k]), radius, fc=colour, ec="k"))
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.margins(0.1)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(
        f"{label}: {sim.n_robots} robots at t = {sim.env.now:.0f} s "
        "(filled: final position and LED; dashed: start)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
