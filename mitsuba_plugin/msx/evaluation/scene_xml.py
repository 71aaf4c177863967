"""The BSDFs of a user's Mitsuba scene that msx can stand in for, found in its XML, and edits of their text.

Pure Python (no Mitsuba): ``msx compare SCENE.xml`` (scene_advice.py) and the tests use it.

**Discovery** (:func:`discover`): every ``<bsdf>`` whose type is ``roughconductor``, ``roughdielectric`` or
``msx_posfree``, also nested inside ``twosided``, ``normalmap``, ``bumpmap``, ``mask`` or ``blendbsdf`` (any
``<bsdf>`` is descended into), in the scene file and the files it ``<include>``s. Attribute values are resolved
with the scene's ``<default>`` values overridden by ``-D`` (``type="$bsdf"`` is a roughconductor when
``bsdf`` is); a BSDF defined once with an ``id`` and used through ``<ref id>`` is one material (the shapes that
use it are counted).

**Edits** (:class:`Edits`): a change is a replacement of a byte span of the file as read — an attribute's
value, a parameter element inserted after a start tag or removed with its line — so that everything else in
the file stays byte-identical. The spans come from expat's byte offsets of each element.
"""

from __future__ import annotations

import re
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

STANDINS = ("roughconductor", "roughdielectric", "msx_posfree")
WRAPPERS = ("twosided", "normalmap", "bumpmap", "mask", "blendbsdf")
# Parameters of msx_posfree that its built-in twins do not have (removed when a candidate is the built-in).
MSX_ONLY = ("surface", "model", "estimator", "max_bounces", "seed", "auto_tolerance", "mis_density",
            "differentiate_directions")
_REF = re.compile(r"\$(\w+)")


class SceneXmlError(Exception):
    """The scene (or a file it includes) cannot be read or parsed; the message is one line."""


@dataclass(eq=False)
class Node:
    tag: str
    attrib: dict
    file: Path
    start: int            # byte offset of '<'
    head_end: int         # byte offset after the start tag's '>'
    end: int = -1         # byte offset after the element (its end tag, or the start tag if it is empty)
    line: int = 0
    parent: "Node | None" = None
    children: list = field(default_factory=list)

    @property
    def empty(self):
        return self.end == self.head_end

    def param(self, name):
        """The child parameter element named `name` (``<float name="alpha" …>``), or None."""
        return next((c for c in self.children if c.attrib.get("name") == name and c.tag != "bsdf"), None)


def _head_end(data: bytes, start: int) -> int:
    """Offset after the '>' closing the start tag at `start` (quotes respected)."""
    quote = None
    i = start + 1
    while i < len(data):
        ch = data[i:i + 1]
        if quote:
            if ch == quote:
                quote = None
        elif ch in (b'"', b"'"):
            quote = ch
        elif ch == b">":
            return i + 1
        i += 1
    raise SceneXmlError("unterminated start tag")


def parse(data: bytes, path: Path) -> Node:
    """The element tree of `data` with byte spans (expat)."""
    parser = xml.parsers.expat.ParserCreate()
    stack, roots = [], []

    def start(tag, attrib):
        s = parser.CurrentByteIndex
        node = Node(tag, dict(attrib), path, s, _head_end(data, s), line=parser.CurrentLineNumber,
                    parent=stack[-1] if stack else None)
        (stack[-1].children if stack else roots).append(node)
        stack.append(node)

    def end(tag):
        node = stack.pop()
        if data[node.head_end - 2:node.head_end] == b"/>":
            node.end = node.head_end
        else:
            i = parser.CurrentByteIndex
            node.end = data.index(b">", i) + 1

    parser.StartElementHandler, parser.EndElementHandler = start, end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        raise SceneXmlError(f"{path}: not valid XML ({e})") from None
    return roots[0]


def read(path) -> bytes:
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise SceneXmlError(f"scene file not found: {path}") from None
    except IsADirectoryError:
        raise SceneXmlError(f"the scene is a folder, not a file: {path}") from None
    except OSError as e:
        raise SceneXmlError(f"cannot read scene file {path}: {e.strerror or e}") from None


def resolve(text: str, values: dict) -> str:
    """`text` with ``$name`` replaced by the parameter's value (unknown names left as they are)."""
    return _REF.sub(lambda m: str(values.get(m.group(1), m.group(0))), text)


@dataclass(eq=False)
class Material:
    """One BSDF element msx can stand in for."""
    key: str              # unique, stable: the id, else built from where it is (file stem, line)
    label: str            # for the page: "copper (roughconductor, GGX α 0.6)"
    node: Node
    kind: str             # roughconductor | roughdielectric | msx_posfree (resolved)
    surface: str          # conductor | dielectric | diffuse
    params: dict          # its parameters, resolved: {name: value}
    wrappers: list        # types of the BSDFs around it, outermost first
    top: Node             # the outermost <bsdf> containing it (what the shapes reference)
    users: int            # shapes using it (inline: 1; by <ref id>: the number of references)
    include_chain: list   # the <include> nodes from the scene file to its file (empty: in the scene file)
    problem: str | None = None  # why msx cannot stand in for it (then it is not evaluated)
    loads: bool = True    # it loads as written (else the other materials' renders use its built-in twin)
    refused: dict = field(default_factory=dict)  # {model: why} candidates msx refuses for it

    @property
    def builtin(self):
        """Mitsuba's single-scattering twin, or None (the diffuse microsurface has none)."""
        return {"conductor": "roughconductor", "dielectric": "roughdielectric"}.get(self.surface)


@dataclass
class Scene:
    path: Path
    files: dict           # {path: bytes} of the scene file and every file it includes
    root: Node
    values: dict          # parameter values: <default>s overridden by -D
    defaults: dict        # the scene file's own <default>s: {name: Node}
    materials: list
    notes: list           # one line per problem met while reading (an include not found, …)
    chains: dict = field(default_factory=dict)  # {included file: the <include> nodes from the scene file to it}
    film: Node | None = None  # the first <film> of a <sensor> (in the scene file or an included one)


def _include_target(node: Node, values, scene_dir: Path):
    name = resolve(node.attrib.get("filename", ""), values)
    for base in (node.file.parent, scene_dir):
        target = (base / name)
        if target.is_file():
            return target
    return None


def discover(path, defines: dict | None = None) -> Scene:
    """The scene at `path` and the materials msx can stand in for (see the module's docstring). Raises
    SceneXmlError if the scene file cannot be read or parsed; an included file that cannot is a note."""
    path = Path(path)
    data = read(path)
    root = parse(data, path)
    if root.tag != "scene":
        raise SceneXmlError(f"{path}: not a Mitsuba scene (its root element is <{root.tag}>)")
    files = {path: data}
    defaults = {c.attrib["name"]: c for c in root.children if c.tag == "default" and "name" in c.attrib}
    values = {k: n.attrib.get("value", "") for k, n in defaults.items()}
    values.update(defines or {})
    notes, found, refs, chains, films = [], [], {}, {}, []

    def visit(node: Node, chain, seen):
        if node.tag == "film" and node.parent is not None and node.parent.tag == "sensor":
            films.append(node)
        if node.tag == "ref" and "id" in node.attrib:
            refs[resolve(node.attrib["id"], values)] = refs.get(resolve(node.attrib["id"], values), 0) + 1
        if node.tag == "include":
            target = _include_target(node, values, path.parent)
            if target is None:
                notes.append(f"{node.file.name}:{node.line}: included file "
                             f"{resolve(node.attrib.get('filename', ''), values)!r} not found")
                return
            if target.resolve() in seen:
                return
            try:
                sub = files.setdefault(target, read(target))
                inc_root = parse(sub, target)
            except SceneXmlError as e:
                notes.append(str(e))
                return
            chains.setdefault(target, chain + [node])
            for child in inc_root.children:
                visit(child, chain + [node], seen | {target.resolve()})
            return
        if node.tag == "bsdf":
            kind = resolve(node.attrib.get("type", ""), values)
            if kind in STANDINS:
                found.append((node, kind, chain))
                return
        for child in node.children:
            visit(child, chain, seen)

    visit(root, [], {path.resolve()})
    materials, keys = [], set()
    for node, kind, chain in found:
        materials.append(_material(node, kind, chain, values, refs, keys))
    return Scene(path, files, root, values, defaults, materials, notes, chains, films[0] if films else None)


def _param_values(node: Node, values):
    out = {}
    for c in node.children:
        if "name" in c.attrib:
            out[resolve(c.attrib["name"], values)] = (
                resolve(c.attrib["value"], values) if "value" in c.attrib else f"<{c.tag}>")
    return out


def _material(node, kind, chain, values, refs, keys):
    params = _param_values(node, values)
    surface = {"roughconductor": "conductor", "roughdielectric": "dielectric"}.get(kind) or \
        params.get("surface", "conductor")
    wrappers, top, p = [], node, node.parent
    while p is not None and p.tag == "bsdf":
        wrappers.insert(0, resolve(p.attrib.get("type", ""), values))
        top, p = p, p.parent
    ids = [resolve(n.attrib["id"], values) for n in (node, top) if "id" in n.attrib]
    top_id = resolve(top.attrib["id"], values) if "id" in top.attrib else None
    shape = top.parent if top.parent is not None and top.parent.tag == "shape" else None
    users = refs.get(top_id, 0) if top_id and shape is None else 1
    if ids:
        base = ids[0]
    elif shape is not None and "id" in shape.attrib:
        base = resolve(shape.attrib["id"], values)
    elif shape is not None and shape.param("filename") is not None:
        base = Path(resolve(shape.param("filename").attrib.get("value", ""), values)).stem
    else:
        base = f"{shape.attrib.get('type', 'shape') if shape is not None else kind}"
    key = base
    if key in keys:
        key = f"{base}@{node.file.stem}:{node.line}"
    keys.add(key)
    alpha = params.get("alpha") or "/".join(params[k] for k in ("alpha_u", "alpha_v") if k in params) or "0.1"
    what = params.get("material") if surface == "conductor" else (
        f"η {params.get('int_ior', 'bk7')}/{params.get('ext_ior', 'air')}" if surface == "dielectric" else "diffuse")
    label = (f"{key} ({kind}{', ' + surface if kind == 'msx_posfree' else ''}"
             f"{', ' + what if what else ''}, {params.get('distribution', 'beckmann')} α {alpha}"
             f"{', in ' + ' › '.join(wrappers) if wrappers else ''})")
    m = Material(key, label, node, kind, surface, params, wrappers, top, users, list(chain))
    if kind == "msx_posfree" and surface not in ("conductor", "dielectric", "diffuse"):
        m.problem = f"msx_posfree with surface={surface!r}: not a surface msx knows"
    return m


# ---------------------------------------------------------------- edits


class Edits:
    """Replacements of byte spans, per file; :meth:`apply` returns the edited bytes of one file."""

    def __init__(self):
        self.spans = {}  # {file: [(start, end, bytes)]}

    def replace(self, file, start, end, text: bytes):
        spans = self.spans.setdefault(Path(file), [])
        if any(start < e and s < end for s, e, _ in spans):
            raise ValueError(f"overlapping edits in {file} at byte {start}")
        spans.append((start, end, text))

    def apply(self, file, data: bytes) -> bytes:
        out, pos = [], 0
        for s, e, text in sorted(self.spans.get(Path(file), []), key=lambda x: (x[0], x[1])):
            out += [data[pos:s], text]
            pos = e
        return b"".join(out) + data[pos:]

    def files(self):
        return list(self.spans)


def _attr_span(data: bytes, node: Node, name: str):
    """(start, end) of the value of attribute `name` in node's start tag, or None."""
    head = data[node.start:node.head_end]
    m = re.search(rb"\s" + re.escape(name.encode()) + rb"\s*=\s*(\"([^\"]*)\"|'([^']*)')", head)
    if not m:
        return None
    g = 2 if m.group(2) is not None else 3
    return node.start + m.start(g), node.start + m.end(g)


def _escape(value: str) -> bytes:
    return value.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;").encode()


def set_attr(edits: Edits, data: bytes, node: Node, name: str, value: str):
    """Sets attribute `name` of node's start tag (its value's span replaced, or the attribute added)."""
    span = _attr_span(data, node, name)
    if span:
        edits.replace(node.file, span[0], span[1], _escape(value))
    else:
        at = node.head_end - (2 if node.empty else 1)
        edits.replace(node.file, at, at, b" " + name.encode() + b'="' + _escape(value) + b'"')


def _indent(data: bytes, offset: int) -> bytes:
    line_start = data.rfind(b"\n", 0, offset) + 1
    m = re.match(rb"[ \t]*", data[line_start:offset])
    return m.group(0)


def set_params(edits: Edits, data: bytes, node: Node, params):
    """Sets the parameters ``[(tag, name, value)]`` of node: an existing one's value attribute, else a new
    ``<tag name value/>`` line after the start tag (an empty element ``<bsdf …/>`` gets an end tag)."""
    own = _indent(data, node.start)
    inner = _indent(data, node.children[0].start) if node.children else own + b"    "
    lines = []
    for tag, name, value in params:
        child = node.param(name)
        if child is not None:
            set_attr(edits, data, child, "value", value)
        else:
            lines.append(inner + b"<" + tag.encode() + b' name="' + name.encode() + b'" value="' + _escape(value)
                         + b'"/>')
    if not lines:
        return
    if node.empty:
        edits.replace(node.file, node.head_end - 2, node.head_end,
                      b">\n" + b"\n".join(lines) + b"\n" + own + b"</" + node.tag.encode() + b">")
    else:
        edits.replace(node.file, node.head_end, node.head_end, b"".join(b"\n" + ln for ln in lines))


def remove(edits: Edits, data: bytes, node: Node):
    """Removes an element, with its line when nothing else is on it."""
    start, end = node.start, node.end
    line_start = data.rfind(b"\n", 0, start) + 1
    line_end = data.find(b"\n", end)
    line_end = len(data) if line_end < 0 else line_end
    if not data[line_start:start].strip() and not data[end:line_end].strip():
        start, end = line_start, min(line_end + 1, len(data))
    edits.replace(node.file, start, end, b"")


def set_model(edits: Edits, scene: Scene, m: Material, model: str):
    """Edits that make material `m` render with `model`: "builtin" (Mitsuba's single-scattering twin) or a
    model of msx_posfree (estimator pt). Parameters the built-in does not take (msx's own) are removed;
    everything else is left as it is (msx_posfree takes every parameter of the built-ins, ``sample_visible``
    included)."""
    data = scene.files[m.node.file]
    node = m.node
    if model == "builtin":
        if m.kind != "msx_posfree":
            return
        from ..plugin.parameters import SURFACE_PARAMS

        set_attr(edits, data, node, "type", m.builtin)
        foreign = {n for s, names in SURFACE_PARAMS.items() if s != m.surface for n in names}
        foreign -= set(SURFACE_PARAMS[m.surface])
        for c in node.children:
            if resolve(c.attrib.get("name", ""), scene.values) in set(MSX_ONLY) | foreign:
                remove(edits, data, c)
        return
    if m.kind != "msx_posfree":
        set_attr(edits, data, node, "type", "msx_posfree")
    drop = ["estimator"] + ([] if model == "auto" else ["auto_tolerance"])
    from ..plugin.parameters import MIS_DENSITY_MODELS

    if not (m.surface == "conductor" and model in MIS_DENSITY_MODELS):
        drop.append("mis_density")
    for c in node.children:
        if resolve(c.attrib.get("name", ""), scene.values) in drop:
            remove(edits, data, c)
    params = [("string", "surface", "dielectric")] if m.kind != "msx_posfree" and m.surface == "dielectric" else []
    set_params(edits, data, node, params + [("string", "model", model)])


def element_after(edits: Edits, scene: Scene, m: Material) -> bytes:
    """The bytes of m's element once `edits` (of that element only) are applied."""
    data = scene.files[m.node.file]
    new = edits.apply(m.node.file, data)
    return new[m.node.start:len(new) - (len(data) - m.node.end)]


def standalone(scene: Scene, m: Material, model: str | None) -> str:
    """A scene of m's BSDF element alone (set to `model`; None: as written) with the scene's <default>s and the
    -D values: to learn, without loading the whole scene, whether Mitsuba and msx accept it."""
    edits = Edits()
    if model is not None:
        set_model(edits, scene, m, model)
    element = element_after(edits, scene, m).decode()
    defaults = "".join(f'<default name="{k}" value="{_escape(str(v)).decode()}"/>' for k, v in scene.values.items())
    return f'<scene version="3.0.0">{defaults}{element}</scene>'


def apply_with_includes(edits: Edits, scene: Scene, write_copy) -> bytes:
    """The scene file's edited bytes. An edited included file is written elsewhere by ``write_copy(file,
    bytes) → the name to include it by`` and the <include> that names it (itself maybe in an included file, then
    edited too) points there."""
    pending = {f for f in edits.files() if f != scene.path}
    while pending:
        deepest = max(pending, key=lambda f: len(scene.chains.get(f, [])))
        pending.discard(deepest)
        chain = scene.chains.get(deepest)
        if not chain:
            continue
        copy = write_copy(deepest, edits.apply(deepest, scene.files[deepest]))
        inc = chain[-1]
        set_attr(edits, scene.files[inc.file], inc, "filename", str(copy))
        if inc.file != scene.path:
            pending.add(inc.file)
    return edits.apply(scene.path, scene.files[scene.path])
