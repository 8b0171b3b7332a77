"""Your own Kilobot program on every robot: ``kilonet run --program my_bot.py[:ClassName]``.

The file is loaded as a module (its folder goes on ``sys.path``, as for a script, so it can
import its neighbours) and the class to run is the one Kilobot subclass it defines, or the one
named after the colon. Every robot runs ``ClassName()``; the swarm comes from ``--placement``
or ``--robots`` (a jittered hex lattice), and the run writes what every scenario writes
(``robots.csv``, ``led.csv``, ``events.csv``, ``poses.csv``, ``summary.json``,
``params.json``) plus ``program.png``: start and final positions, LEDs and paths.

A run file's ``[program]`` section, and ``--set program.NAME=VALUE``, set class attributes
the program declares (``gain = 0.5`` in its class body) on every robot before ``setup()``
(:func:`program_settings`): a program's own parameters, checked like kilonet's.

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
import importlib.util
import inspect
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kilonet.scenarios.base import RunResult, Scenario, ScenarioError

from kilonet.errors import ProgramFault, exception_line, read_text
from kilonet.message import PayloadError
from kilonet.robot import RESERVED_PREFIX, Kilobot
from kilonet.watchdog import BusyCallError

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = [
    "ProgramError",
    "load_program",
    "parse_spec",
    "program_scenario",
    "program_settings",
    "reported_as_user_errors",
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
            raise ProgramError(
                f"{path}: defines several Kilobot subclasses ({names}); name one: "
                f"--program {path}:{defined[0].__name__}"
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
    out: dict[str, Any] = {}
    for name, value in settings.items():
        default = None
        for klass in cls.__mro__:
            if klass is Kilobot:
                break
            if name in vars(klass):
                default = vars(klass)[name]
                break
        if name.startswith("_") or not isinstance(default, _SETTING_TYPES):
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
    spec: str, settings: dict[str, Any] | None = None, where: Callable[[str], str] = str
) -> Scenario:
    """A scenario that runs the program ``spec`` (``FILE.py[:ClassName]``) on every robot,
    with ``settings`` (checked by :func:`program_settings`) set on each robot's program before
    its ``setup()`` (``where(name)``: where a setting came from, for an error).

    Raises
    ------
    ProgramError
        If the program cannot be loaded (:func:`load_program`) or a setting is refused.
    """
    path, cls = load_program(spec)
    label = f"{path.name}:{cls.__name__}"
    values = program_settings(cls, dict(settings or {}), where)

    def build(_i: int) -> Kilobot:
        robot = cls()
        for name, value in values.items():
            setattr(robot, name, value)
        return robot

    def program(params: Any, positions: Any):
        return build

    def metrics(_sim: Simulation) -> dict[str, Any]:
        return {"program": label}

    def figure(result: RunResult, out_dir: Path) -> None:
        _figure(result, label, out_dir / "program.png")

    return Scenario(
        name="program",
        summary=f"your program {label} on every robot",
        program=program,
        robots=0,
        metrics=metrics,
        outputs=figure,
    )


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
