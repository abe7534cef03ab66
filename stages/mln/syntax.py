"""The .mln file format as pracmln reads it: parse into formulas, and write them back.

Supported: `//` comments, predicate declarations `Has(word, page)`, domain declarations
`word = {a, b}`, weighted formulas `1.5 Has("a", p) => Topic("C4", p)`, hard formulas with a
trailing `.`, the connectives `!`, `^`, `v`, `=>`, `<=>` (binding from strongest to weakest),
parentheses, `+var` template variables, and quoted or capitalised constants.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field
from typing import Callable, Union

from mlnseq.catalog.errors import BadInput


@dataclass(frozen=True)
class Var:
    name: str
    expand: bool = False  # `+name`: one formula per constant, each with its own weight


@dataclass(frozen=True)
class Const:
    value: str


Term = Union[Var, Const]


@dataclass(frozen=True)
class Atom:
    predicate: str
    args: tuple[Term, ...]
    column: int = field(default=0, compare=False)  # 1-based position in its line (0: unknown)


@dataclass(frozen=True)
class Not:
    operand: "Formula"


@dataclass(frozen=True)
class And:
    operands: tuple["Formula", ...]


@dataclass(frozen=True)
class Or:
    operands: tuple["Formula", ...]


@dataclass(frozen=True)
class Implies:
    body: "Formula"
    head: "Formula"


@dataclass(frozen=True)
class Equiv:
    left: "Formula"
    right: "Formula"


Formula = Union[Atom, Not, And, Or, Implies, Equiv]


@dataclass(frozen=True)
class WeightedFormula:
    formula: Formula
    weight: float | None  # None: hard
    line: int = 0
    column: int = 0

    @property
    def hard(self) -> bool:
        return self.weight is None


@dataclass
class MLN:
    predicates: dict[str, tuple[str, ...]] = field(default_factory=dict)  # name -> argument domains
    domains: dict[str, list[str]] = field(default_factory=dict)  # declared constants
    formulas: list[WeightedFormula] = field(default_factory=list)
    mutex: dict[str, tuple[bool, ...]] = field(default_factory=dict)  # `page!` arguments


class MLNSyntaxError(BadInput):
    """A .mln file that cannot be parsed: names the file, line and column."""


_TOKEN = re.compile(
    r"""(?P<space>\s+)
      | (?P<equiv><=>) | (?P<implies>=>)
      | (?P<string>"[^"]*")
      | (?P<number>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w]))
      | (?P<plusvar>\+[A-Za-z_]\w*)
      | (?P<ident>[A-Za-z_]\w*)
      | (?P<punct>[()!^,={}.])
    """,
    re.VERBOSE,
)


@dataclass(frozen=True)
class _Token:
    kind: str
    text: str
    column: int  # 1-based


class _Parser:
    def __init__(self, text: str, where: str, line: int, column0: int = 0):
        self.where, self.line = where, line
        self.tokens = self._tokenize(text, column0)
        self.pos = 0

    def _tokenize(self, text: str, column0: int) -> list[_Token]:
        tokens, i = [], 0
        while i < len(text):
            match = _TOKEN.match(text, i)
            if match is None:
                raise self.error(column0 + i + 1, f"unexpected character {text[i]!r}")
            kind = match.lastgroup
            if kind != "space":
                value = match.group()
                if kind == "ident" and value == "v":
                    kind = "or"
                elif kind == "punct":
                    kind = {"!": "not", "^": "and"}.get(value, value)
                tokens.append(_Token(kind, value, column0 + i + 1))
            i = match.end()
        return tokens

    def error(self, column: int, message: str) -> MLNSyntaxError:
        return MLNSyntaxError(f"{self.where}:{self.line}:{column}: {message}")

    def peek(self) -> _Token | None:
        return self.tokens[self.pos] if self.pos < len(self.tokens) else None

    def end_column(self) -> int:
        last = self.tokens[-1] if self.tokens else None
        return last.column + len(last.text) if last else 1

    def expect(self, kind: str, what: str) -> _Token:
        token = self.peek()
        if token is None:
            raise self.error(self.end_column(), f"expected {what}, found the end of the line")
        if token.kind != kind:
            raise self.error(token.column, f"expected {what}, found {token.text!r}")
        self.pos += 1
        return token

    def accept(self, kind: str) -> _Token | None:
        token = self.peek()
        if token is not None and token.kind == kind:
            self.pos += 1
            return token
        return None

    def formula(self) -> Formula:
        left = self.implication()
        if self.accept("equiv"):
            return Equiv(left, self.implication())
        return left

    def implication(self) -> Formula:
        body = self.disjunction()
        if self.accept("implies"):
            return Implies(body, self.disjunction())
        return body

    def disjunction(self) -> Formula:
        operands = [self.conjunction()]
        while self.accept("or"):
            operands.append(self.conjunction())
        return operands[0] if len(operands) == 1 else Or(tuple(operands))

    def conjunction(self) -> Formula:
        operands = [self.negation()]
        while self.accept("and"):
            operands.append(self.negation())
        return operands[0] if len(operands) == 1 else And(tuple(operands))

    def negation(self) -> Formula:
        if self.accept("not"):
            return Not(self.negation())
        if self.accept("("):
            inner = self.formula()
            self.expect(")", "')'")
            return inner
        return self.atom()

    def atom(self) -> Atom:
        name = self.expect("ident", "a predicate, '!' or '('")
        self.expect("(", f"'(' after {name.text}")
        args = [self.term()]
        while self.accept(","):
            args.append(self.term())
        self.expect(")", "',' or ')'")
        return Atom(name.text, tuple(args), name.column)

    def term(self) -> Term:
        token = self.peek()
        if token is None:
            raise self.error(self.end_column(), "expected a variable or a constant, found the end of the line")
        self.pos += 1
        if token.kind == "string":
            return Const(token.text[1:-1])
        if token.kind == "plusvar":
            return Var(token.text[1:], expand=True)
        if token.kind == "ident":
            return Var(token.text) if token.text[0].islower() else Const(token.text)
        if token.kind == "number":
            return Const(token.text)
        raise self.error(token.column, f"expected a variable or a constant, found {token.text!r}")

    def done(self) -> None:
        token = self.peek()
        if token is not None:
            raise self.error(token.column, f"unexpected {token.text!r} after the formula")


def _strip_comment(line: str) -> str:
    in_string = False
    for i, char in enumerate(line):
        if char == '"':
            in_string = not in_string
        elif not in_string and line.startswith("//", i):
            return line[:i]
    return line


_DECLARATION = re.compile(r"^\s*([A-Za-z_]\w*)\s*\(\s*([A-Za-z_]\w*!?\s*(?:,\s*[A-Za-z_]\w*!?\s*)*)\)\s*$")
_DOMAIN = re.compile(r"^\s*([a-z_]\w*)\s*=\s*\{(.*)\}\s*$")
_WEIGHT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)(?=\s)")


@functools.lru_cache(maxsize=4096)  # a weights table's formulas are parsed again at every read (frozen: shared safely)
def parse_formula(text: str, where: str = "<formula>", line: int = 1, column0: int = 0) -> Formula:
    """Parse one formula (no weight, no trailing '.')."""
    parser = _Parser(text, where, line, column0)
    try:
        formula = parser.formula()
    except RecursionError:
        raise parser.error(column0 + 1, "the formula nests '(' or '!' too deeply") from None
    parser.done()
    return formula


def parse_mln(text: str, where: str = "<mln>") -> MLN:
    """Parse a .mln text; syntax errors name ``where``, the line and the column."""
    mln = MLN()
    for number, raw in enumerate(text.splitlines(), start=1):
        line = _strip_comment(raw).rstrip()
        if not line.strip():
            continue
        stripped = line.lstrip()
        indent = len(line) - len(stripped)
        if stripped.startswith("#"):
            raise MLNSyntaxError(f"{where}:{number}:{indent + 1}: directive {stripped.split()[0]!r} is not supported")
        if (domain := _DOMAIN.match(line)) is not None:
            values = [v.strip().strip('"') for v in domain.group(2).split(",") if v.strip()]
            mln.domains.setdefault(domain.group(1), []).extend(values)
            continue
        weight_match = _WEIGHT.match(line)
        if weight_match is not None:
            body_start = weight_match.end()
            formula = parse_formula(line[body_start:], where, number, body_start)
            weight = float(weight_match.group(1))
            if not math.isfinite(weight):
                raise MLNSyntaxError(f"{where}:{number}:{indent + 1}: weight {weight_match.group(1)} is not a finite "
                                     "number; end the formula with '.' to make it hard")
            mln.formulas.append(WeightedFormula(formula, weight, number, indent + 1))
            continue
        if line.endswith("."):
            formula = parse_formula(line[:-1], where, number)
            mln.formulas.append(WeightedFormula(formula, None, number, indent + 1))
            continue
        if (declaration := _DECLARATION.match(line)) is not None:
            name = declaration.group(1)
            args = [a.strip() for a in declaration.group(2).split(",")]
            if name in mln.predicates:
                raise MLNSyntaxError(f"{where}:{number}:{indent + 1}: predicate {name} is declared twice")
            mln.predicates[name] = tuple(a.rstrip("!") for a in args)
            mln.mutex[name] = tuple(a.endswith("!") for a in args)
            continue
        # Not a declaration: parse it as a formula to point at the error, else say what is missing.
        parse_formula(line, where, number)
        raise MLNSyntaxError(
            f"{where}:{number}:{indent + 1}: a formula needs a weight in front (e.g. 0.0) or a '.' at the end (hard)"
        )
    return mln


def format_term(term: Term) -> str:
    if isinstance(term, Const):
        return f'"{term.value}"'
    return f"+{term.name}" if term.expand else term.name


def format_formula(formula: Formula, parent: int = 0) -> str:
    """pracmln syntax, with parentheses only where precedence needs them."""
    if isinstance(formula, Atom):
        return f"{formula.predicate}({','.join(format_term(t) for t in formula.args)})"
    if isinstance(formula, Not):
        return "!" + format_formula(formula.operand, 5)
    if isinstance(formula, And):
        text, level = " ^ ".join(format_formula(o, 4) for o in formula.operands), 4
    elif isinstance(formula, Or):
        text, level = " v ".join(format_formula(o, 3) for o in formula.operands), 3
    elif isinstance(formula, Implies):
        text, level = f"{format_formula(formula.body, 3)} => {format_formula(formula.head, 3)}", 2
    else:
        text, level = f"{format_formula(formula.left, 2)} <=> {format_formula(formula.right, 2)}", 1
    return f"({text})" if parent >= level else text


def format_weighted(item: WeightedFormula) -> str:
    text = format_formula(item.formula)
    return f"{text}." if item.hard else f"{format_weight(item.weight):<11} {text}"


def format_weight(weight: float) -> str:
    """Six decimals where they give the weight back exactly, else every digit it needs (1e-07 never becomes
    0.000000, which reads back as "learn me")."""
    fixed = f"{weight:.6f}"
    return fixed if float(fixed) == weight else repr(float(weight))


def atoms(formula: Formula) -> list[Atom]:
    """The atoms of a formula, left to right."""
    if isinstance(formula, Atom):
        return [formula]
    if isinstance(formula, Not):
        return atoms(formula.operand)
    if isinstance(formula, (And, Or)):
        return [a for o in formula.operands for a in atoms(o)]
    if isinstance(formula, Implies):
        return atoms(formula.body) + atoms(formula.head)
    return atoms(formula.left) + atoms(formula.right)


def map_atoms(formula: Formula, change: Callable[[Atom], Atom]) -> Formula:
    """The same formula with every atom replaced by ``change(atom)``."""
    if isinstance(formula, Atom):
        return change(formula)
    if isinstance(formula, Not):
        return Not(map_atoms(formula.operand, change))
    if isinstance(formula, (And, Or)):
        return type(formula)(tuple(map_atoms(o, change) for o in formula.operands))
    if isinstance(formula, Implies):
        return Implies(map_atoms(formula.body, change), map_atoms(formula.head, change))
    return Equiv(map_atoms(formula.left, change), map_atoms(formula.right, change))


def substitute(formula: Formula, binding: dict[str, str]) -> Formula:
    """Replace variables named in ``binding`` by constants."""
    return map_atoms(formula, lambda atom: Atom(atom.predicate, tuple(
        Const(binding[t.name]) if isinstance(t, Var) and t.name in binding else t for t in atom.args), atom.column))
