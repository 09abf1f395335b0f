"""Open Inventor 2.1 ASCII text -> a tree of `Node`s: the tokenizer, the nodes and fields
this reader knows, DEF and USE. Syntax errors read `file:line: what`.

No maintained Python reader of Inventor files exists, so the tokenizer and parser are here,
apart from what the nodes mean (`host.scene.inventor`), so parsing never builds the scene.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from host.scene.errors import SceneError

HEADER = re.compile(r"#Inventor V2\.[01] ascii\b")
_TOKEN = re.compile(r'(#[^\n]*)|("(?:[^"\\\n]|\\.)*")|([{}\[\]()|])|([^\s{}\[\]()|",#]+)|(\n)')

# Field kinds: 'f' one number, 'v3' three, 'rot' four (axis, angle), 'mv3' one or a [list] of
# triples, 'mf' one or a [list] of numbers, 'mi' one or a [list] of integers, 'b' TRUE/FALSE,
# 'enum' a word or (A | B), 'str' one or a [list] of strings.
_CAMERA = {
    "position": "v3",
    "orientation": "rot",
    "heightAngle": "f",
    "focalDistance": "f",
    "nearDistance": "f",
    "farDistance": "f",
    "aspectRatio": "f",
    "viewportMapping": "enum",
}
_NODES: dict[str, dict[str, str]] = {
    "Separator": {
        "renderCaching": "enum",
        "boundingBoxCaching": "enum",
        "renderCulling": "enum",
        "pickCulling": "enum",
    },
    "Group": {},
    "Transform": {
        "translation": "v3",
        "rotation": "rot",
        "scaleFactor": "v3",
        "scaleOrientation": "rot",
        "center": "v3",
    },
    "Translation": {"translation": "v3"},
    "Rotation": {"rotation": "rot"},
    "Scale": {"scaleFactor": "v3"},
    "Material": {
        "ambientColor": "mv3",
        "diffuseColor": "mv3",
        "specularColor": "mv3",
        "emissiveColor": "mv3",
        "shininess": "mf",
        "transparency": "mf",
    },
    "Coordinate3": {"point": "mv3"},
    "IndexedFaceSet": {"coordIndex": "mi"},
    "Sphere": {"radius": "f"},
    "Cone": {"bottomRadius": "f", "height": "f", "parts": "enum"},
    "Cylinder": {"radius": "f", "height": "f", "parts": "enum"},
    "Cube": {"width": "f", "height": "f", "depth": "f"},
    "PerspectiveCamera": _CAMERA,
    "PointLight": {"on": "b", "intensity": "f", "color": "v3", "location": "v3"},
    "DirectionalLight": {"on": "b", "intensity": "f", "color": "v3", "direction": "v3"},
    "Info": {"string": "str"},
}
_GROUPS = ("Separator", "Group")


@dataclass
class Node:
    """A parsed node: its type, line, fields (value, line) and children."""

    kind: str
    line: int
    fields: dict = field(default_factory=dict)
    children: list = field(default_factory=list)

    def get(self, name: str, default):
        return self.fields[name][0] if name in self.fields else default


class Parser:
    """Tokens (with lines) -> a tree of `Node`s; DEF names resolve to the same Node."""

    def __init__(self, text: str, source: str):
        self.source = source
        first = text.split("\n", 1)[0]
        if not HEADER.match(first):
            raise SceneError(
                source,
                1,
                "not an Open Inventor 2.1 ASCII file (the first line "
                "must be '#Inventor V2.1 ascii')",
            )
        self.toks: list[str] = []
        self.lines: list[int] = []
        line = 1
        for m in _TOKEN.finditer(text):
            if m.group(5):
                line += 1
            elif not m.group(1):
                self.toks.append(m.group(0))
                self.lines.append(line)
        self.n_lines = line
        self.i = 0
        self.defs: dict[str, Node] = {}

    def error(self, what: str, at: int | None = None) -> SceneError:
        i = self.i if at is None else at
        line = self.lines[i] if i < len(self.lines) else self.n_lines
        return SceneError(self.source, line, what)

    def peek(self) -> str | None:
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self, what: str) -> str:
        tok = self.peek()
        if tok is None:
            raise self.error(f"the file ends where {what} should be")
        self.i += 1
        return tok

    def parse(self) -> list[Node]:
        roots = []
        while self.peek() is not None:
            roots.append(self.node())
        return roots

    def node(self) -> Node:
        at = self.i
        tok = self.take("a node")
        if tok == "USE":
            name = self.take("a name after USE")
            if name not in self.defs:
                raise self.error(f"USE {name!r}: no node was DEF'd with that name", at)
            return self.defs[name]
        name = None
        if tok == "DEF":
            name = self.take("a name after DEF")
            at = self.i
            tok = self.take("a node")
        if tok not in _NODES:
            if tok in "{}[]()|" or not re.fullmatch(r"[A-Za-z_][\w]*", tok):
                raise self.error(f"expected a node, got {tok!r}", at)
            raise self.error(f"unknown node {tok!r} (supported: {', '.join(sorted(_NODES))})", at)
        node = Node(tok, self.lines[at])
        if self.take(f"'{{' after {tok}") != "{":
            raise self.error(f"expected '{{' after {tok}", self.i - 1)
        schema = _NODES[tok]
        while True:
            nxt = self.peek()
            if nxt is None:
                raise self.error(f"{tok} opened on line {node.line} is never closed")
            if nxt == "}":
                self.i += 1
                if name is not None:  # only now: a node cannot USE itself
                    self.defs[name] = node
                return node
            after = self.toks[self.i + 1] if self.i + 1 < len(self.toks) else None
            if nxt in ("DEF", "USE") or after == "{":
                if tok not in _GROUPS:
                    raise self.error(
                        f"{tok} cannot have child nodes (only Separator and Group can)"
                    )
                node.children.append(self.node())
                continue
            if nxt not in schema:
                known = ", ".join(schema) or "none"
                raise self.error(f"{tok} has no field {nxt!r} (fields: {known})")
            if nxt in node.fields:
                raise self.error(f"{tok}: field {nxt!r} given twice")
            line = self.lines[self.i]
            self.i += 1
            node.fields[nxt] = (self.value(tok, nxt, schema[nxt]), line)

    # -- field values ---------------------------------------------------------------------------

    def value(self, node: str, name: str, kind: str):
        where = f"{node}.{name}"
        if kind == "f":
            return self.number(where)
        if kind in ("v3", "rot"):
            return tuple(self.number(where) for _ in range(3 if kind == "v3" else 4))
        if kind == "b":
            tok = self.take(f"{where}'s value")
            if tok not in ("TRUE", "FALSE", "0", "1"):
                raise self.error(f"{where} is TRUE or FALSE, got {tok!r}", self.i - 1)
            return tok in ("TRUE", "1")
        if kind == "enum":
            return self.enum(where)
        one = {
            "mv3": lambda: tuple(self.number(where) for _ in range(3)),
            "mf": lambda: self.number(where),
            "mi": lambda: self.integer(where),
            "str": lambda: self.string(where),
        }[kind]
        if self.peek() != "[":
            return [one()]
        self.i += 1
        out = []
        while self.peek() != "]":
            if self.peek() is None:
                raise self.error(f"{where}: '[' is never closed")
            out.append(one())
        self.i += 1
        return out

    def number(self, where: str) -> float:
        tok = self.take(f"a number for {where}")
        try:
            x = float(tok)
        except ValueError:
            raise self.error(f"{where}: expected a number, got {tok!r}", self.i - 1) from None
        if not math.isfinite(x):
            raise self.error(f"{where}: non-finite number {tok!r}", self.i - 1)
        return x

    def integer(self, where: str) -> int:
        tok = self.take(f"an integer for {where}")
        if not re.fullmatch(r"[+-]?\d+", tok):
            raise self.error(f"{where}: expected an integer, got {tok!r}", self.i - 1)
        return int(tok)

    def string(self, where: str) -> str:
        tok = self.take(f"a string for {where}")
        if not tok.startswith('"'):
            raise self.error(f"{where}: expected a quoted string, got {tok!r}", self.i - 1)
        return tok[1:-1]

    def enum(self, where: str) -> set[str]:
        if self.peek() != "(":
            return {self.take(f"a value for {where}")}
        self.i += 1
        words = set()
        while True:
            words.add(self.take(f"a value for {where}"))
            tok = self.take(f"')' closing {where}")
            if tok == ")":
                return words
            if tok != "|":
                raise self.error(f"{where}: expected '|' or ')', got {tok!r}", self.i - 1)
