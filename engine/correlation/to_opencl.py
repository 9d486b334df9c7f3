"""OpenCL C generated from the Python definition of the interpolation.

Works on the source of the functions of :mod:`engine.correlation.interpolation` (scalar
arithmetic in a small subset of Python) and their C signatures
(:data:`engine.correlation.interpolation.SIGNATURES`), and returns OpenCL C text: one C
function per Python function, with the same name and the same operations in the same
order. The OpenCL kernel includes this text, so the interpolation it runs is the one the
numpy reference and the numba kernels run; nothing is retyped by hand.

The subset: assignments (also tuple unpacking of a call's results or of a cell), ``+=``
and the like, ``if``/``else`` on a flag, ``return`` of one value or a tuple, arithmetic with
``+ - *`` and unary minus, ``table[row, column]`` reads, calls to the other translated
functions (``f(...)`` or ``f(...)[i]`` on the right of an assignment), ``np.floor`` and
``int``. Anything else raises :class:`TranslationError`, so a change to the Python source
that the translation cannot follow fails loudly (the tests build the result).

How results come back in C: a function with one result returns it; one with several takes
one pointer per result after its arguments; ``cell`` returns a ``cell_t`` struct.
"""

from __future__ import annotations

import ast
import inspect
import textwrap
from collections.abc import Callable, Sequence
from typing import Any

CELL_FIELDS = (("int", "b00"), ("int", "b01"), ("int", "b10"), ("int", "b11"),
               ("float", "tx"), ("float", "ty"), ("float", "tz"))

CELL_STRUCT = ("typedef struct {\n"
               + "".join(f"    {ctype} {name};\n" for ctype, name in CELL_FIELDS)
               + "} cell_t;\n")

_C_TYPES = {"float": "float", "int": "int", "cell_t": "cell_t",
            "table": "__global const float *"}
_OPERATORS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*"}


class TranslationError(ValueError):
    """The Python source uses something the OpenCL translation does not know."""


def translate(
    functions: Sequence[Callable[..., Any]],
    signatures: dict[str, tuple[tuple[str, ...], str | tuple[str, ...]]],
) -> str:
    """OpenCL C for ``functions`` (callees first), preceded by the ``cell_t`` struct.

    Parameters
    ----------
    functions : sequence of Python functions
        Written in the subset the module docstring describes.
    signatures : dict
        Per function name: the C types of its arguments (``"float"``, ``"int"``,
        ``"cell_t"`` or ``"table"``) and of its result (one type or a tuple).
    """
    parts = [CELL_STRUCT]
    for func in functions:
        parts.append(_Function(func, signatures).source())
    return "\n".join(parts)


class _Function:
    """The translation of one function."""

    def __init__(self, func: Callable[..., Any], signatures: dict[str, Any]) -> None:
        tree = ast.parse(textwrap.dedent(inspect.getsource(func)))
        node = tree.body[0]
        if not isinstance(node, ast.FunctionDef):
            raise TranslationError(f"{func.__name__}: not a function definition")
        self.node = node
        self.name = node.name
        self.signatures = signatures
        if self.name not in signatures:
            raise TranslationError(f"{self.name}: no C signature given")
        arg_types, result = signatures[self.name]
        names = [a.arg for a in node.args.args]
        if len(names) != len(arg_types):
            raise TranslationError(f"{self.name}: {len(names)} arguments, "
                                   f"{len(arg_types)} C types")
        self.types: dict[str, str] = dict(zip(names, arg_types, strict=True))
        self.arguments = names
        self.result = result
        self.locals: dict[str, str] = {}
        self.temporaries = 0

    # ------------------------------------------------------------------ output
    def source(self) -> str:
        body: list[str] = []
        for statement in self.node.body:
            if _is_docstring(statement):
                continue
            body += self._statement(statement, 1)
        args = [f"{_C_TYPES[self.types[n]]}{'' if self.types[n] == 'table' else ' '}{n}"
                for n in self.arguments]
        if isinstance(self.result, tuple):
            args += [f"{_C_TYPES[t]} *out{i}" for i, t in enumerate(self.result)]
            returns = "void"
        else:
            returns = _C_TYPES[self.result]
        declarations = [f"    {_C_TYPES[t]} {n};" for n, t in self.locals.items()]
        head = f"inline {returns} {self.name}({', '.join(args)})"
        return head + "\n{\n" + "\n".join(declarations + body) + "\n}\n"

    # ------------------------------------------------------------------ statements
    def _statement(self, node: ast.stmt, depth: int) -> list[str]:
        pad = "    " * depth
        if isinstance(node, ast.Assign):
            if len(node.targets) != 1:
                raise self._error(node, "chained assignment")
            return [pad + line for line in self._assign(node.targets[0], node.value)]
        if isinstance(node, ast.AugAssign):
            if not isinstance(node.target, ast.Name) or type(node.op) not in _OPERATORS:
                raise self._error(node, "augmented assignment")
            value, _ = self._expression(node.value)
            op = _OPERATORS[type(node.op)]
            return [f"{pad}{node.target.id} {op}= {value};"]
        if isinstance(node, ast.If):
            test, _ = self._expression(node.test)
            lines = [f"{pad}if ({test}) {{"]
            for statement in node.body:
                lines += self._statement(statement, depth + 1)
            if node.orelse:
                lines.append(f"{pad}}} else {{")
                for statement in node.orelse:
                    lines += self._statement(statement, depth + 1)
            lines.append(f"{pad}}}")
            return lines
        if isinstance(node, ast.Return):
            return [pad + line for line in self._return(node)]
        raise self._error(node, type(node).__name__)

    def _assign(self, target: ast.expr, value: ast.expr) -> list[str]:
        if isinstance(target, ast.Tuple):
            names = [self._name(t) for t in target.elts]
            if isinstance(value, ast.Name) and self._type_of(value.id) == "cell_t":
                if len(names) != len(CELL_FIELDS):
                    raise self._error(target, "a cell unpacks into seven names")
                lines = []
                for (ctype, field), name in zip(CELL_FIELDS, names, strict=True):
                    self._declare(name, ctype)
                    lines.append(f"{name} = {value.id}.{field};")
                return lines
            if isinstance(value, ast.Call):
                callee, results = self._callee(value)
                if not isinstance(results, tuple) or len(results) != len(names):
                    raise self._error(value, f"{callee} does not return {len(names)} values")
                for name, ctype in zip(names, results, strict=True):
                    self._declare(name, ctype)
                return [self._call_statement(value, [f"&{n}" for n in names])]
            raise self._error(value, "tuple assignment from anything but a call or a cell")
        name = self._name(target)
        if isinstance(value, ast.Subscript) and isinstance(value.value, ast.Call):
            callee, results = self._callee(value.value)
            index = _constant_index(value)
            if not isinstance(results, tuple):
                raise self._error(value, f"{callee} returns one value")
            self._declare(name, results[index])
            pointers = []
            for i, ctype in enumerate(results):
                if i == index:
                    pointers.append(f"&{name}")
                else:
                    temp = self._temporary(ctype)
                    pointers.append(f"&{temp}")
            return [self._call_statement(value.value, pointers)]
        text, ctype = self._expression(value)
        self._declare(name, ctype)
        return [f"{name} = {text};"]

    def _return(self, node: ast.Return) -> list[str]:
        if node.value is None:
            raise self._error(node, "bare return")
        if isinstance(self.result, tuple):
            if not isinstance(node.value, ast.Tuple) or len(node.value.elts) != len(self.result):
                raise self._error(node, f"must return {len(self.result)} values")
            lines = [f"*out{i} = {self._expression(e)[0]};"
                     for i, e in enumerate(node.value.elts)]
            return lines + ["return;"]
        if self.result == "cell_t":
            if not isinstance(node.value, ast.Tuple) or len(node.value.elts) != len(CELL_FIELDS):
                raise self._error(node, "a cell is returned as a tuple of seven values")
            temp = self._temporary("cell_t")
            lines = [f"{temp}.{field} = {self._expression(e)[0]};"
                     for (_, field), e in zip(CELL_FIELDS, node.value.elts, strict=True)]
            return lines + [f"return {temp};"]
        return [f"return {self._expression(node.value)[0]};"]

    def _call_statement(self, call: ast.Call, pointers: list[str]) -> str:
        callee, _ = self._callee(call)
        args = [self._expression(a)[0] for a in call.args]
        return f"{callee}({', '.join(args + pointers)});"

    # ------------------------------------------------------------------ expressions
    def _expression(self, node: ast.expr) -> tuple[str, str]:
        """C text of an expression and its type ("float" or "int")."""
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                raise self._error(node, f"constant {node.value!r}")
            if isinstance(node.value, int):
                return str(node.value), "int"
            return f"{float(node.value)!r}f", "float"
        if isinstance(node, ast.Name):
            return node.id, self._type_of(node.id)
        if isinstance(node, ast.BinOp) and type(node.op) in _OPERATORS:
            left, lt = self._expression(node.left)
            right, rt = self._expression(node.right)
            ctype = "int" if lt == rt == "int" else "float"
            return f"({left} {_OPERATORS[type(node.op)]} {right})", ctype
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            text, ctype = self._expression(node.operand)
            return f"(-{text})", ctype
        if isinstance(node, ast.Subscript):
            if not (isinstance(node.value, ast.Name) and self._type_of(node.value.id) == "table"):
                raise self._error(node, "indexing anything but the table")
            index = node.slice
            if not (isinstance(index, ast.Tuple) and len(index.elts) == 2):
                raise self._error(node, "the table is read as table[row, column]")
            row, _ = self._expression(index.elts[0])
            col, _ = self._expression(index.elts[1])
            return f"{node.value.id}[({row}) * CHANNELS + ({col})]", "float"
        if isinstance(node, ast.Call):
            func = node.func
            if (isinstance(func, ast.Attribute) and func.attr == "floor"
                    and isinstance(func.value, ast.Name) and func.value.id == "np"):
                return f"floor({self._expression(node.args[0])[0]})", "float"
            if isinstance(func, ast.Name) and func.id == "int":
                return f"((int)({self._expression(node.args[0])[0]}))", "int"
            callee, result = self._callee(node)
            if isinstance(result, tuple):
                raise self._error(node, f"{callee} returns several values: assign them")
            args = [self._expression(a)[0] for a in node.args]
            return f"{callee}({', '.join(args)})", result
        raise self._error(node, type(node).__name__)

    # ------------------------------------------------------------------ helpers
    def _callee(self, call: ast.Call) -> tuple[str, str | tuple[str, ...]]:
        if not isinstance(call.func, ast.Name) or call.func.id not in self.signatures:
            raise self._error(call, "call of an untranslated function")
        if call.keywords:
            raise self._error(call, "keyword arguments")
        return call.func.id, self.signatures[call.func.id][1]

    def _name(self, node: ast.expr) -> str:
        if not isinstance(node, ast.Name):
            raise self._error(node, "assignment to anything but a name")
        return node.id

    def _declare(self, name: str, ctype: str) -> None:
        known = self.types.get(name) or self.locals.get(name)
        if known is None:
            self.locals[name] = ctype
        elif known != ctype:
            raise TranslationError(f"{self.name}: {name} is both {known} and {ctype}")

    def _temporary(self, ctype: str) -> str:
        self.temporaries += 1
        name = f"tmp{self.temporaries}"
        self.locals[name] = ctype
        return name

    def _type_of(self, name: str) -> str:
        ctype = self.types.get(name) or self.locals.get(name)
        if ctype is None:
            raise TranslationError(f"{self.name}: {name} is used before it is assigned")
        return ctype

    def _error(self, node: ast.AST, what: str) -> TranslationError:
        line = getattr(node, "lineno", 0) + self.node.lineno - 1
        return TranslationError(f"{self.name} (line {line} of its source): cannot translate "
                                f"{what} to OpenCL C")


def _is_docstring(node: ast.stmt) -> bool:
    return isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(
        node.value.value, str)


def _constant_index(node: ast.Subscript) -> int:
    if not (isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, int)):
        raise TranslationError("only constant indices of a call's results can be translated")
    return int(node.slice.value)
