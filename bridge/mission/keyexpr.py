"""Zenoh key expressions in the mission file: checked when the file is read (pure: no Zenoh).

Zenoh refuses a key expression that breaks its rules only when the bridge declares a subscriber
or puts on it, so a bad key in the file would pass ``zab check`` and stop ``zab run`` with a
traceback (or lose every value put on it). These are Zenoh's rules (its ``keyexpr`` type,
``KeyExpr(text)`` in Python, which the tests compare with):

- chunks (the parts between ``/``) are not empty: no leading, trailing or double ``/``;
- ``#`` and ``?`` are forbidden;
- ``*`` is a whole chunk (``*``: one chunk, ``**``: any number) or ``$*`` inside a chunk, and
  ``$`` appears only in ``$*``;
- the form is canonical: ``**/**`` is written ``**``, ``**/*`` is ``*/**``, a chunk ``$*``
  is ``*`` and ``$*$*`` is ``$*``.

A key may hold placeholders (``{node}``, ``{src}``, ``{dst}``, ``{key}``): each is checked as
the plain name it becomes (node names and family members hold no ``/*$#?{}``).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Collection
from typing import Annotated

from pydantic import AfterValidator

__all__ = ["AnyTemplateKey", "FixedKey", "NodeTemplateKey", "PeerTemplateKey",
           "canonical_chunks", "key_expr_problem"]

_PLACEHOLDER = re.compile(r"\{([^{}/]*)\}")
_PLAIN = "x"  # what a placeholder stands for while the key is checked: a plain name
_STARS = re.compile(r"(?:\$\*)+")


def _braces(text: str, templates: Collection[str] | None) -> str | None:
    """What is wrong with the placeholders of ``text`` (None: nothing)."""
    for name in _PLACEHOLDER.findall(text):
        if not name:
            return "an empty placeholder {}: name it, e.g. {node}"
        if templates is not None and name not in templates:
            if not templates:
                return f"placeholder {{{name}}}: this key is used as written, none is filled in"
            allowed = ", ".join("{" + t + "}" for t in sorted(templates))
            return f"unknown placeholder {{{name}}}; allowed here: {allowed}"
    if re.search(r"[{}]", _PLACEHOLDER.sub(_PLAIN, text)):
        return "'{' and '}' only around a placeholder, e.g. {node}"
    return None


def _chunk_problem(chunk: str) -> str | None:
    """What is wrong with one non-empty chunk, placeholders filled in (None: nothing)."""
    if chunk in ("*", "**"):
        return None
    for i, c in enumerate(chunk):
        if c == "$" and chunk[i + 1:i + 2] != "*":
            return "'$' only in '$*' (a wildcard inside a chunk)"
        if c == "*" and chunk[i - 1:i] != "$":
            return "'*' only as a whole chunk ('*' or '**') or in '$*'"
    return None


def canonical_chunks(chunks: list[str]) -> list[str]:
    """``chunks`` (each valid) in Zenoh's canonical form: ``$*$*`` → ``$*``, a lone ``$*`` →
    ``*``, and in each run of ``*`` and ``**`` chunks the ``*`` first and one ``**`` last."""
    out: list[str] = []
    run: list[str] = []
    for chunk in [*(_STARS.sub("$*", c) for c in chunks), ""]:
        chunk = "*" if chunk == "$*" else chunk
        if chunk in ("*", "**"):
            run.append(chunk)
            continue
        if "**" in run:
            run = ["*"] * run.count("*") + ["**"]
        out += run
        run = []
        if chunk:
            out.append(chunk)
    return out


def key_expr_problem(text: str, templates: Collection[str] | None = None) -> str | None:
    """Why ``text`` is not a valid Zenoh key expression, in a few words; None if it is.

    ``templates``: the placeholders allowed in it (None: any name, checked elsewhere; empty:
    none, the key is used as written)."""
    if not text:
        return "empty"
    wrong = _braces(text, templates)
    if wrong is not None:
        return wrong
    for c, why in (("#", ""), ("?", " (it starts a selector's parameters)")):
        if c in text:
            return f"'{c}' is forbidden{why}"
    chunks = text.split("/")
    if "" in chunks:
        kept = "/".join(c for c in chunks if c)
        where = ("a leading '/'" if not chunks[0] else "a trailing '/'" if not chunks[-1]
                 else "'//'")
        return f"empty chunk: {where}" + (f" (write {kept!r})" if kept else "")
    for chunk in chunks:
        wrong = _chunk_problem(_PLACEHOLDER.sub(_PLAIN, chunk))
        if wrong is not None:
            return f"{wrong}, not {chunk!r}"
    canon = canonical_chunks(chunks)
    if canon != chunks:
        return f"not canonical (write {'/'.join(canon)!r})"
    return None


def _checked(templates: Collection[str] | None) -> Callable[[str], str]:
    def check(text: str) -> str:
        why = key_expr_problem(text, templates)
        if why is not None:
            raise ValueError(f"invalid Zenoh key expression {text!r}: {why}")
        return text
    return check


AnyTemplateKey = Annotated[str, AfterValidator(_checked(None))]
"""A key whose placeholders the channel table checks (channels, queries, image channels)."""
NodeTemplateKey = Annotated[str, AfterValidator(_checked({"node"}))]
"""A key where ``{node}`` is the node itself (a node's keyspace)."""
PeerTemplateKey = Annotated[str, AfterValidator(_checked({"src", "node", "dst"}))]
"""A key heard from each peer: ``{src}`` the peer, ``{node}``/``{dst}`` this node."""
FixedKey = Annotated[str, AfterValidator(_checked(()))]
"""A key used as written (no placeholders)."""
