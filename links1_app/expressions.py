"""Per-frame parameter values of ``links1 animate``: ``-D angle='7.5*f'`` and ``--frames 0:48``.

A value is a comma-separated list of arithmetic expressions over the frame number ``f`` and
the time ``t = f / fps`` (seconds), with the constants ``pi``, ``e``, ``tau`` and the
functions of :data:`FUNCTIONS`; ``-D eye='14*sin(radians(7.5*f)), 9, 14*cos(radians(7.5*f))'``
is three of them. Expressions are read with :mod:`ast` and evaluated node by node over that
whitelist: no name, attribute, subscript or call outside it is ever looked up, so a value
cannot run code. A value that neither reads ``f``/``t`` nor calls a function (``32``, ``sphere``, a file name) is
passed to the scene unchanged for every frame.
"""
from __future__ import annotations

import ast
import math
import operator

from links1.errors import UsageError

#: the functions an expression may call
FUNCTIONS = {name: getattr(math, name) for name in (
    "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "sqrt", "exp", "log",
    "log10", "floor", "ceil", "radians", "degrees", "hypot", "fmod", "copysign")}
FUNCTIONS.update(abs=abs, min=min, max=max, round=round)
#: the names an expression may read besides ``f`` and ``t``
CONSTANTS = {"pi": math.pi, "e": math.e, "tau": math.tau}
VARIABLES = ("f", "t")

_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod, ast.Pow: operator.pow}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}
#: the largest exponent ``**`` accepts (a huge power is an error, not an hour of arithmetic)
MAX_POWER = 1024


class Expression:
    """One ``-D`` value: :meth:`value` ``(f, t)`` -> the string the scene's ``$name`` gets."""

    def __init__(self, name: str, text: str):
        self.name, self.text = name, text
        self.parts = _parse_list(text)       # None: a plain string, the same every frame
        if self.parts is not None:
            self.value(0, 0.0)               # names, calls and arithmetic checked now, not at frame 17

    @property
    def varies(self) -> bool:
        """Whether the value depends on the frame."""
        return self.parts is not None and any(_uses_variable(p) for p in self.parts)

    def value(self, f: int, t: float) -> str:
        if self.parts is None:
            return self.text
        env = {"f": f, "t": t}
        return ", ".join(_format(self._eval(p, env)) for p in self.parts)

    def _eval(self, node, env):
        try:
            v = _evaluate(node, env)
        except ArithmeticError as e:   # 1/0, log(0), overflow
            raise UsageError(f"-D {self.name}={self.text!r}: {e} at f={env['f']}") from None
        except _Refused as e:
            raise UsageError(f"-D {self.name}={self.text!r}: {e}") from None
        if isinstance(v, complex) or not math.isfinite(v):
            raise UsageError(f"-D {self.name}={self.text!r}: not a finite real number at f={env['f']} ({v})")
        return v


class _Refused(Exception):
    """Something an expression may not contain (a name, a call, an operator)."""


def _parse_list(text):
    """The value's expressions, or None for a value that is the scene's text as it stands: one that
    neither reads ``f``/``t`` nor calls a function (``32``, ``0, 9, 14``, ``sphere``,
    ``meshes/vase.patch``). A value that does is evaluated, and all of it must be arithmetic."""
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError:
        return None
    if not any(isinstance(n, ast.Call) or (isinstance(n, ast.Name) and n.id in VARIABLES) for n in ast.walk(tree)):
        return None
    body = tree.body
    return list(body.elts) if isinstance(body, ast.Tuple) else [body]


def _uses_variable(node) -> bool:
    return any(isinstance(n, ast.Name) and n.id in VARIABLES for n in ast.walk(node))


def _evaluate(node, env):
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise _Refused(f"{node.value!r} is not a number")
        return node.value
    if isinstance(node, ast.Name):
        if node.id in env:
            return env[node.id]
        if node.id in CONSTANTS:
            return CONSTANTS[node.id]
        raise _Refused(f"unknown name {node.id!r} (use f, t, {', '.join(CONSTANTS)})")
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        a, b = _evaluate(node.left, env), _evaluate(node.right, env)
        if isinstance(node.op, ast.Pow) and abs(b) > MAX_POWER:
            raise _Refused(f"exponent {b} is larger than {MAX_POWER}")
        return _BINARY[type(node.op)](a, b)
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_evaluate(node.operand, env))
    if isinstance(node, ast.Call):
        fn = node.func.id if isinstance(node.func, ast.Name) else None
        if fn not in FUNCTIONS or node.keywords:
            raise _Refused(f"unknown function {ast.unparse(node.func)!r} (known: {', '.join(sorted(FUNCTIONS))})")
        try:
            return FUNCTIONS[fn](*(_evaluate(a, env) for a in node.args))
        except TypeError as e:
            raise _Refused(f"{fn}(): {e}") from None
        except ValueError as e:   # math domain error
            raise ArithmeticError(f"{fn}(): {e}") from None
    raise _Refused(f"{ast.unparse(node)!r} is not arithmetic over f and t")


def _format(v) -> str:
    """A number as the scene reads it: integral values as integers (``res=64``), others with
    every digit (``repr``: the float the expression gave, not a rounded one)."""
    if isinstance(v, int) or (isinstance(v, float) and v.is_integer() and abs(v) < 2 ** 53):
        return str(int(v))
    return repr(float(v))


def parse_frames(text: str) -> list[int]:
    """``--frames``: ``A:B`` (frames A .. B-1, Python's range), ``A:B:S``, or ``N`` (frames 0 .. N-1)."""
    parts = text.split(":")
    try:
        nums = [int(p) for p in parts]
    except ValueError:
        raise UsageError(f"--frames {text!r}: expected START:STOP[:STEP] or COUNT (integers)") from None
    if len(nums) == 1:
        nums = [0, nums[0]]
    if len(nums) > 3 or (len(nums) == 3 and nums[2] == 0):
        raise UsageError(f"--frames {text!r}: expected START:STOP[:STEP] with STEP != 0")
    frames = list(range(*nums))
    if not frames:
        raise UsageError(f"--frames {text!r} holds no frame")
    if min(frames) < 0:
        raise UsageError(f"--frames {text!r}: frame numbers must be >= 0")
    return frames


def frame_values(defines, frames, fps: float) -> list[dict]:
    """Per frame, ``$name`` -> value string, from ``defines`` ([(name, text), ...], ``-D``)."""
    if not fps > 0 or not math.isfinite(fps):
        raise UsageError(f"--fps must be a positive number, got {fps}")
    exprs = [Expression(name, text) for name, text in defines]
    return [{e.name: e.value(f, f / fps) for e in exprs} for f in frames]
