"""The parameter definitions of the core (include/structured_light_stabilizer/
<stage>/*.def, common/params.h) read from Python: the dynamic_reconfigure .cfg
files add their live parameters from them (add_params), and scripts/check-params
renders the docs' parameter tables from what a .cfg adds (ParamTable).

A .def line is one macro call, e.g.
  SLS_PARAM(double, min_depth, 0.8, 0.05, 20.0, "Near end of the depth range (m)")
Lines starting with // are comments; a call may span lines.
"""
import ast
import os
import re

_HERE = os.path.dirname(os.path.realpath(__file__))
INCLUDE_ROOT = os.path.join(_HERE, "..", "include", "structured_light_stabilizer")

_CALL = re.compile(r"\b(SLS_PARAM|SLS_ENUM|SLS_INT_ENUM|SLS_FIXED|SLS_GROUP|SLS_SECTION)\s*\(", re.S)


def _split_args(text):
    """Splits a macro's argument text at top-level commas (strings and brackets kept)."""
    args, depth, cur, i = [], 0, "", 0
    while i < len(text):
        ch = text[i]
        if ch == '"':
            j = i + 1
            while text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            cur += text[i:j + 1]
            i = j + 1
            continue
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        if ch == "," and depth == 0:
            args.append(cur.strip())
            cur = ""
        else:
            cur += ch
        i += 1
    args.append(cur.strip())
    return args


def _literal(text):
    """A C++ literal or string (adjacent strings joined) as a Python value."""
    t = text.strip()
    if t.startswith('"'):
        return "".join(ast.literal_eval(s) for s in re.findall(r'"(?:[^"\\]|\\.)*"', t))
    if t in ("true", "false"):
        return t == "true"
    t = re.sub(r"(?<=[0-9.])[fF]\b", "", t)
    return ast.literal_eval(t)


def read_def(path):
    """The entries of a .def file (path relative to include/structured_light_stabilizer/)."""
    full = os.path.join(INCLUDE_ROOT, path)
    with open(full) as f:
        text = re.sub(r"//[^\n]*", "", f.read())
    entries = []
    for m in _CALL.finditer(text):
        depth, j = 1, m.end()
        while depth:
            if text[j] == '"':
                j = text.index('"', j + 1)
                while text[j - 1] == "\\":
                    j = text.index('"', j + 1)
            elif text[j] == "(":
                depth += 1
            elif text[j] == ")":
                depth -= 1
            j += 1
        a = _split_args(text[m.end():j - 1])
        kind = m.group(1)
        if kind == "SLS_PARAM":
            entries.append(dict(kind="param", type=a[0], name=a[1], default=_literal(a[2]),
                                min=_literal(a[3]), max=_literal(a[4]), doc=_literal(a[5])))
        elif kind in ("SLS_ENUM", "SLS_INT_ENUM"):
            choices = [c.split(":", 1) for c in _literal(a[3]).split("|")]
            names = [c[0] for c in choices]
            docs = [c[1] if len(c) > 1 else c[0] for c in choices]
            default = a[2].split("::")[-1]
            entries.append(dict(kind="enum" if kind == "SLS_ENUM" else "int_enum", type=a[0], name=a[1],
                                default=default, choices=names, choice_docs=docs, doc=_literal(a[4])))
        elif kind == "SLS_FIXED":
            entries.append(dict(kind="fixed", type=a[0], name=a[1], doc=_literal(a[3])))
        elif kind == "SLS_SECTION":
            entries.append(dict(kind="section", name=a[0], type=_literal(a[1])))
        else:
            entries.append(dict(kind="group", type=a[0], name=a[1], file=_literal(a[2]), group=_literal(a[3])))
    return entries


def _default_index(entry):
    """The enumerator named in the .def's default (kFast -> the choice 'fast')."""
    enumerator = entry["default"]
    want = re.sub(r"^k", "", enumerator).lower()
    for i, c in enumerate(entry["choices"]):
        if c.replace("_", "") == want.replace("_", ""):
            return i
    raise ValueError("%s: default %s matches no choice of %s" % (entry["name"], enumerator, entry["choices"]))


def add_params(gen, target, path, groups=None):
    """Adds the live parameters of a .def (and its nested groups) to a
    dynamic_reconfigure ParameterGenerator `gen` (for enums), into `target`
    (gen or one of its groups). `groups` collects the groups made by name."""
    from dynamic_reconfigure.parameter_generator_catkin import bool_t, double_t, int_t, str_t
    types = {"int": int_t, "double": double_t, "bool": bool_t}
    groups = {} if groups is None else groups
    base = target
    for e in read_def(path):
        if e["kind"] == "section":
            if e["name"] not in groups:
                groups[e["name"]] = base.add_group(e["name"], type=e["type"])
            target = groups[e["name"]]
            continue
        if e["kind"] == "param":
            if e["type"] == "bool":
                target.add(e["name"], bool_t, 0, e["doc"], e["default"])
            else:
                target.add(e["name"], types[e["type"]], 0, e["doc"], e["default"], e["min"], e["max"])
        elif e["kind"] in ("enum", "int_enum"):
            is_str = e["kind"] == "enum"
            consts = [gen.const(n, str_t if is_str else int_t, n if is_str else i, d)
                      for i, (n, d) in enumerate(zip(e["choices"], e["choice_docs"]))]
            enum = gen.enum(consts, e["doc"])
            d = _default_index(e)
            if is_str:
                target.add(e["name"], str_t, 0, e["doc"], e["choices"][d], edit_method=enum)
            else:
                target.add(e["name"], int_t, 0, e["doc"], d, 0, len(e["choices"]) - 1, edit_method=enum)
        elif e["kind"] == "group":
            sub = target
            if e["group"]:
                if e["group"] not in groups:
                    groups[e["group"]] = gen.add_group(e["group"], type="tab")
                sub = groups[e["group"]]
            add_params(gen, sub, e["file"], groups)
    return groups
