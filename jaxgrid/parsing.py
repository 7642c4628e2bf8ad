"""Backtracking parser combinators over words, and English numerals: the machinery of
:mod:`jaxgrid.language`.

A parser maps ``(words, i, failure)`` to every ``(value, j)`` it can match from word ``i``
(every alternative is kept, so patterns may nest freely); each mismatch is noted in the
:class:`Failure`, which keeps the furthest position and what was expected there, so a failed
parse names the first word it could not read and the words it wanted.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from typing import Any

__all__ = [
    "MINUS_WORDS", "NUMBER_WORDS", "Failure", "Parser", "alt", "lit", "number", "numeral_value",
    "seq", "word",
]  # fmt: skip

Parser = Callable[[Sequence[str], int, "Failure"], list]


class Failure:
    """The furthest point a parse reached: ``pos`` (0-based word), ``expected`` (what would
    have matched there) and ``bad_number`` (a numeral a number slot refused, if any)."""

    def __init__(self):
        self.pos, self.expected = -1, []
        self.bad_number: tuple[int, str, str] | None = None  # (position, numeral, why)

    def note(self, pos: int, what: str) -> None:
        if pos > self.pos:
            self.pos, self.expected = pos, [what]
        elif pos == self.pos and what not in self.expected:
            self.expected.append(what)

    def note_number(self, pos: int, numeral: str, why: str) -> None:
        """A numeral where a number goes, but not one the slot allows: the first one wins."""
        if self.bad_number is None or pos < self.bad_number[0]:
            self.bad_number = (pos, numeral, why)


def lit(phrase: str, value: Any = None) -> Parser:
    """The words of ``phrase``, in order; its value is ``value``."""
    words = phrase.split()

    def parse(ws, i, fail):
        for k, w in enumerate(words):
            if i + k >= len(ws) or ws[i + k] != w:
                fail.note(i + k, repr(w))
                return []
        return [(value, i + len(words))]

    return parse


def word(options: dict[str, Any], what: str) -> Parser:
    """One word among ``options`` (word -> value); ``what`` names the slot in errors."""

    def parse(ws, i, fail):
        if i < len(ws) and ws[i] in options:
            return [(options[ws[i]], i + 1)]
        fail.note(i, what)
        return []

    return parse


def alt(*parsers: Parser) -> Parser:
    """Every match of every parser."""

    def parse(ws, i, fail):
        return [r for p in parsers for r in p(ws, i, fail)]

    return parse


def seq(*parsers: Parser, build: Callable[..., Any]) -> Parser:
    """Match ``parsers`` in order; ``build`` gets the non-None values in order."""

    def parse(ws, i, fail):
        partial = [((), i)]
        for p in parsers:
            partial = [
                (vals + (() if v is None else (v,)), j2)
                for vals, j in partial
                for v, j2 in p(ws, j, fail)
            ]
            if not partial:
                return []
        return [(build(*vals), j) for vals, j in partial]

    return parse


# --------------------------------------------------------------------------------------
# English numerals: read whole, with their sign, so that a number is refused by what it is
# --------------------------------------------------------------------------------------
#: The number words a number slot accepts ("one" 1 ... "ten" 10); digits "1" to "10" too.
NUMBER_WORDS = ("one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")
_NUMBER = {w: k for k, w in enumerate(NUMBER_WORDS, start=1)} | {
    str(k): k for k in range(1, len(NUMBER_WORDS) + 1)
}
#: Number words outside the accepted ones, read so that they are refused by value.
_OTHER_NUMBER_WORDS = {
    "zero": 0, "eleven": 11, "twelve": 12, "thirteen": 13, "fourteen": 14, "fifteen": 15,
    "sixteen": 16, "seventeen": 17, "eighteen": 18, "nineteen": 19, "twenty": 20, "thirty": 30,
    "forty": 40, "fifty": 50, "sixty": 60, "seventy": 70, "eighty": 80, "ninety": 90,
    "hundred": 100, "thousand": 1000, "million": 10**6, "billion": 10**9,
}  # fmt: skip
#: Words that make the number after them negative.
MINUS_WORDS = ("minus", "negative")
_DIGITS = re.compile(r"[+-]?\d+(?:[.,]\d+)*")


def numeral_value(word: str) -> int | float | None:
    """The value of a one-word numeral, or None when ``word`` is none.

    Numerals are the number words ("one" to "ten", and "zero", "eleven" to "ninety",
    "hundred" to "billion") and digits with an optional sign, decimal point or digit groups
    ("3", "-1", "+2", "1.5", "1,000": :func:`jaxgrid.language.normalize` keeps them whole).
    The value is what the numeral says, so that a number the grammar does not accept can be
    refused by what it is (negative, fractional or out of range) instead of being misread.
    """
    if word in _NUMBER:
        return _NUMBER[word]
    if word in _OTHER_NUMBER_WORDS:
        return _OTHER_NUMBER_WORDS[word]
    if _DIGITS.fullmatch(word):
        plain = word.replace(",", "")
        return float(plain) if "." in plain else int(plain)
    return None


def _why_not(value: int | float, high: int) -> str:
    """Why a numeral of ``value`` is not one of the grammar's numbers 1..``high``."""
    if value < 0:
        return "is negative"
    if value != int(value):
        return "is not a whole number"
    if not 1 <= value <= high:
        return "is out of range"
    return "is not written as the grammar writes numbers (no sign, leading zero or comma)"


def number(high: int, what: str, rule: str) -> Parser:
    """A number 1..``high``: a word ("three") or plain digits ("3"); ``what`` names the slot
    in grammar errors, ``rule`` states its range in number errors.

    Any other numeral in its place ("-1", "minus two", "1.5", "+2", "eleven") fails with a
    :meth:`Failure.note_number`, which :func:`jaxgrid.language.parse` reports before any
    grammar error: the sentence says a number the monitor cannot represent, and no other
    reading is meant.
    """
    if not 1 <= high <= len(NUMBER_WORDS):
        raise ValueError(f"a number slot takes 1..{len(NUMBER_WORDS)} at most, got {high}")

    def parse(ws, i, fail):
        j = i + 1 if i < len(ws) and ws[i] in MINUS_WORDS else i
        value = numeral_value(ws[j]) if j < len(ws) else None
        if value is None:
            fail.note(i, what)
            return []
        if j == i and ws[i] in _NUMBER and _NUMBER[ws[i]] <= high:
            return [(_NUMBER[ws[i]], i + 1)]
        value = -value if j > i else value
        fail.note_number(i, " ".join(ws[i : j + 1]), f"{_why_not(value, high)}: {rule}")
        return []

    return parse
