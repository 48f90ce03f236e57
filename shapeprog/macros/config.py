"""The settings of a ShapeMOD discovery run: their defaults (:data:`DEFAULTS`, the spec's ``sa_config``
values), their limits (:data:`LIMITS`) and :func:`load_config`, which reads a YAML file of them.
"""
from __future__ import annotations

from pathlib import Path

from ..errors import ParseError
from ..limits import decode

__all__ = [
    "DEFAULTS",
    "SWITCHES",
    "load_config",
]


#: The spec's defaults (``configs/shapemod/default.yaml`` holds the same values).
DEFAULTS: dict = {
    "num_rounds": 5, "cand_cluster_num": 10000, "cand_cluster_size": 20, "cand_abs_num": 20, "cand_max_changes": 2,
    "cand_max_error": 0.05, "cand_max_avg_error": 0.02, "cand_max_lines": 4, "abs_shape_num": 1000,
    "abs_order_num": 1000, "abs_beam_size": 10, "abs_max_error": 0.06, "abs_add_threshold": 0.05,
    "order_thresh": 1.0, "func_change_thresh": 0.5, "err_shape_perc": 0.7, "err_const_perc": 0.9, "prec": 2,
    "scale_prec": 20, "cluster_eps": 0.05, "gen_limit": 300, "selection": "greedy", "search": "beam",
    "milp_pool": 60, "milp_time_limit": 120, "milp_warm": True, "chunk": 50,
    "cluster_weighting": True, "generalise": True, "valid_rules": True, "order_filter": True,
}
#: The switches of the paper's Table 5 ablations (each True in the full method): clusters drawn with weights
#: ``1 - d / max d`` (False: uniformly), generalisation (snapping and edits; False: none), the valid-macro rules
#: i-iv of a candidate (False: every prefix the language accepts), filterBadOrders after each round (False:
#: every ordering stays). "No beam" is ``abs_beam_size: 1``.
SWITCHES = ("cluster_weighting", "generalise", "valid_rules", "order_filter")
_CHOICES = {"selection": ("greedy", "milp"), "search": ("beam", "exact")}
#: The range of every numeric setting (inclusive): a value outside is refused when the config is loaded.
LIMITS: dict = {
    "num_rounds": (0, 100), "cand_cluster_num": (1, 10**6), "cand_cluster_size": (1, 10**4), "cand_abs_num": (1, 10**4),
    "cand_max_changes": (0, 100), "cand_max_error": (0.0, 10.0), "cand_max_avg_error": (0.0, 10.0),
    "cand_max_lines": (1, 100), "abs_shape_num": (1, 10**6), "abs_order_num": (1, 10**6), "abs_beam_size": (1, 1000),
    "abs_max_error": (0.0, 10.0), "abs_add_threshold": (0.0, 10.0), "order_thresh": (0.0, 10.0),
    "func_change_thresh": (0.0, 10.0), "err_shape_perc": (0.0, 1.0), "err_const_perc": (0.0, 1.0), "prec": (0, 10),
    "scale_prec": (1, 10**4), "cluster_eps": (0.0, 10.0), "gen_limit": (1, 10**6), "milp_pool": (1, 10**4),
    "milp_time_limit": (1, 10**6), "chunk": (1, 10**6),
}


#: Bytes of a config file (the shipped ones: under 2 KB); a larger file is refused before it is read.
MAX_CONFIG_BYTES = 1 << 20
#: Characters of a value shown in an error (a longer one is cut).
_SHOWN = 60


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= _SHOWN else f"{text[:_SHOWN]}... ({len(text)} characters)"


def load_config(path: str | Path | None = None, **overrides) -> dict:
    """The defaults, updated from a YAML file and then ``overrides``.

    The file may hold at most :data:`MAX_CONFIG_BYTES` and no YAML alias (``*name``), so that what it loads
    to is no larger than its text.

    Raises:
        ParseError: an unknown key or a value of the wrong type, naming the file and the key; a file over
            :data:`MAX_CONFIG_BYTES`, an alias.
    """
    cfg = dict(DEFAULTS)
    items: list[tuple[str, object, str, int, int]] = []  # key, value, file, line, column
    if path is not None:
        import yaml  # lazy: PyYAML only when a settings file is read

        with open(path, "rb") as f:
            raw = f.read(MAX_CONFIG_BYTES + 1)
        if len(raw) > MAX_CONFIG_BYTES:
            raise ParseError(f"a config has at most {MAX_CONFIG_BYTES} bytes (MAX_CONFIG_BYTES)", str(path), 1, 1, "")
        text = decode(raw, str(path))
        try:
            alias = next((e for e in yaml.parse(text) if isinstance(e, yaml.AliasEvent)), None)
            if alias is None:
                data = yaml.safe_load(text)
            node = yaml.compose(text)
        except yaml.YAMLError as e:
            mark = getattr(e, "problem_mark", None)
            line, col = (mark.line + 1, mark.column + 1) if mark is not None else (1, 1)
            raise ParseError(f"not YAML: {getattr(e, 'problem', None) or e}", str(path), line, col, "") from None
        except (ValueError, RecursionError) as e:  # an integer of too many digits, nesting too deep
            raise ParseError(f"not a config: {type(e).__name__}: {str(e)[:120]}", str(path), 1, 1, "") from None
        if alias is not None:  # each alias could repeat a large value: a few lines could load to gigabytes
            mark = alias.start_mark
            raise ParseError(f"YAML aliases (*{alias.anchor[:_SHOWN]}) are not allowed in a config", str(path),
                             mark.line + 1, mark.column + 1, f"*{alias.anchor}"[:_SHOWN])
        if node is None:  # an empty file, or comments only: the defaults
            data, node = {}, yaml.MappingNode("tag:yaml.org,2002:map", [])
        if not isinstance(data, dict) or not isinstance(node, yaml.MappingNode):
            raise ParseError("a config is a mapping of settings", str(path), 1, 1, "")
        marks = {k.value: (k.start_mark.line + 1, k.start_mark.column + 1) for k, _ in node.value
                 if isinstance(k, yaml.ScalarNode)}
        items += [(k, v, str(path), *marks.get(str(k), (1, 1))) for k, v in data.items()]
    items += [(k, v, "<overrides>", 1, 1) for k, v in overrides.items() if v is not None]
    for k, v, where, line, col in items:
        if k not in DEFAULTS:
            raise ParseError(f"unknown setting {_shown(k)}", where, line, col, str(k)[:_SHOWN])
        want = type(DEFAULTS[k])
        if want is float and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        if not isinstance(v, want) or isinstance(v, bool) != (want is bool):
            raise ParseError(f"setting {_shown(k)} must be {want.__name__}, got {_shown(v)}", where, line, col,
                             str(k)[:_SHOWN])
        if k in _CHOICES and v not in _CHOICES[k]:
            raise ParseError(f"setting {k!r} must be one of {_CHOICES[k]}, got {_shown(v)}", where, line, col, str(k))
        if k in LIMITS and not LIMITS[k][0] <= v <= LIMITS[k][1]:
            raise ParseError(f"setting {k!r} must be in {LIMITS[k][0]}..{LIMITS[k][1]}, got {v!r}", where, line, col,
                             str(k))
        cfg[k] = v
    return cfg
