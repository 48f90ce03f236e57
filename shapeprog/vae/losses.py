"""The losses of the ShapeAssembly generative model: per-line terms, leaf, bbox and KL, with the spec's weights.

:func:`line_losses` compares a node's predicted lines with its target (the reference's ``ProgLoss``),
:func:`program_loss` sums every term over the nodes of a shape and weights them with
:data:`LOSS_WEIGHTS`. Cross-entropies and L1 terms are sums; the leaf term is a mean per node. The terms
and where they differ from the reference: ``docs/shapeassembly_vae.md``.

Example:
    >>> from shapeprog.lang import parse
    >>> from shapeprog.vae.model import VAE
    >>> from shapeprog.vae.vectors import program_to_tree
    >>> tree = program_to_tree(parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\n"
    ...     "cube0 = Cuboid(0.5, 0.25, 0.5, True)\\nattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n"))
    >>> total, terms = program_loss(VAE(hidden_dim=32)(tree), tree)
    >>> sorted(terms) == sorted(LOSS_WEIGHTS)
    True
"""
from __future__ import annotations

from typing import Mapping

import torch
import torch.nn.functional as F

from .model import VAEOutput
from .vectors import ALIGNED, AXIS, CMD, CUBE1, CUBE2, CUBE3, FACE, VectorNode, l1_mask

__all__ = ["LINE_TERMS", "LOSS_WEIGHTS", "MACRO_LINE_TERMS", "MACRO_LOSS_WEIGHTS", "kl_loss", "leaf_loss", "line_losses",
           "macro_line_losses", "macro_program_loss", "program_loss"]

#: The weight of each term (the reference's defaults: CE 1, L1 50, KL 0.1).
LOSS_WEIGHTS = {
    "cmd": 1.0, "cub_prm": 50.0, "xyz_prm": 50.0, "uv_prm": 50.0, "sym_prm": 50.0, "cub": 1.0,
    "sym_cub": 1.0, "sq_cub": 1.0, "axis": 1.0, "face": 1.0, "align": 1.0, "leaf": 1.0, "bb": 50.0, "kl": 0.1,
}
#: The terms of :func:`line_losses`.
LINE_TERMS = ("cmd", "cub_prm", "xyz_prm", "uv_prm", "sym_prm", "cub", "sym_cub", "sq_cub", "axis", "face", "align")
_CUBOID, _ATTACH, _REFLECT, _TRANSLATE, _SQUEEZE = 1, 2, 3, 4, 5
_ALIGN_POS_WEIGHT = 0.2


def _ce(pred: torch.Tensor, target: torch.Tensor, rows: torch.Tensor, part: slice) -> torch.Tensor:
    """Summed cross-entropy of the one-hot ``part`` over ``rows`` (0 when there are none)."""
    if rows.numel() == 0:
        return pred.new_zeros(())
    return F.cross_entropy(pred[rows, part], target[rows, part].argmax(dim=1), reduction="sum")


def _l1(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
    return (mask[rows] * (pred[rows] - target[rows]).abs()).sum()


def line_losses(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """The per-line terms of one node.

    Args:
        pred: (T, 63) float, predicted lines (logits for one-hots and aligned).
        target: (T, 63) float, the target lines ``[l1 .. lL, stop]``.
        mask: (T, 63) float, the L1 entries; None derives it from ``target`` (:func:`~shapeprog.vae.vectors.l1_mask`).

    Returns:
        Scalar tensors named as :data:`LINE_TERMS`: ``cmd`` CE over all rows; ``cub_prm``, ``xyz_prm``,
        ``uv_prm``, ``sym_prm`` L1 on the Cuboid dims, attach coordinates, squeeze u, v, translate count
        and distance; ``cub`` CE on both cubes of attach lines; ``sym_cub`` and ``axis`` CE on the cube
        and axis of reflect and translate lines; ``sq_cub`` CE on the three squeeze cubes; ``face``;
        ``align`` BCE-with-logits (pos_weight 0.2) on the aligned flag of every Cuboid line but the first.
    """
    if pred.dim() != 2 or pred.shape != target.shape or pred.shape[1] != 63:
        raise ValueError(f"pred and target must both be (T, 63), got {tuple(pred.shape)} and {tuple(target.shape)}")
    mask = l1_mask(target) if mask is None else mask
    cmds = target[:, CMD].argmax(dim=1)
    rows = {c: (cmds == c).nonzero().flatten() for c in (_CUBOID, _ATTACH, _REFLECT, _TRANSLATE, _SQUEEZE)}
    sym = torch.cat([rows[_REFLECT], rows[_TRANSLATE]])
    later = rows[_CUBOID][1:]
    align = pred.new_zeros(())
    if later.numel():
        pw = torch.tensor(_ALIGN_POS_WEIGHT, dtype=pred.dtype, device=pred.device)
        align = F.binary_cross_entropy_with_logits(pred[later, ALIGNED], target[later, ALIGNED], reduction="sum",
                                                   pos_weight=pw)
    return {
        "cmd": F.cross_entropy(pred[:, CMD], cmds, reduction="sum"),
        "cub_prm": _l1(pred, target, mask, rows[_CUBOID]),
        "xyz_prm": _l1(pred, target, mask, rows[_ATTACH]),
        "uv_prm": _l1(pred, target, mask, rows[_SQUEEZE]),
        "sym_prm": _l1(pred, target, mask, rows[_TRANSLATE]),
        "cub": _ce(pred, target, rows[_ATTACH], CUBE1) + _ce(pred, target, rows[_ATTACH], CUBE2),
        "sym_cub": _ce(pred, target, sym, CUBE1),
        "sq_cub": sum((_ce(pred, target, rows[_SQUEEZE], c) for c in (CUBE1, CUBE2, CUBE3)), pred.new_zeros(())),
        "axis": _ce(pred, target, sym, AXIS),
        "face": _ce(pred, target, rows[_SQUEEZE], FACE),
        "align": align,
    }


def leaf_loss(logits: torch.Tensor, is_leaf: torch.Tensor) -> torch.Tensor:
    """Mean BCE-with-logits of a node's leaf logits (K,) against targets (K,) (1 = leaf, bbox included)."""
    return F.binary_cross_entropy_with_logits(logits, is_leaf.to(logits.dtype))


def kl_loss(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """``-sum(1 + logvar - mu^2 - exp(logvar))``: the KL divergence to N(0, I) times 2 (no ½, as the reference)."""
    return -(1 + logvar - mu.pow(2) - logvar.exp()).sum()


def program_loss(output: VAEOutput, tree: VectorNode, weights: Mapping[str, float] | None = None,
                 kl: bool = True) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The weighted training loss of one shape.

    Args:
        output: :meth:`shapeprog.vae.model.VAE.forward` of ``tree``.
        tree: the target tree.
        weights: per-term weights; default :data:`LOSS_WEIGHTS` (a missing term weighs 0).
        kl: include the KL term (False for a non-variational pass, where it is reported as 0).

    Returns:
        ``(total, terms)``: the weighted sum (scalar) and every unweighted term, each summed over the
        nodes (:data:`LINE_TERMS`, ``leaf``, ``bb`` the L1 of the root bbox dims, ``kl``).
    """
    def node_terms(node, out):
        return {**line_losses(out.lines, node.target_seq()), "leaf": _leaf_term(node, out, len(node.cuboid_rows))}

    return _tree_loss(output, tree, LINE_TERMS, node_terms, LOSS_WEIGHTS if weights is None else weights, kl)


def _leaf_term(node, out, count: int) -> torch.Tensor:
    """:func:`leaf_loss` of a node's first ``count`` leaf logits: a cuboid without a child program is a leaf."""
    is_leaf = torch.tensor([float(j >= len(node.children) or node.children[j] is None) for j in range(count)],
                           dtype=out.leaf.dtype, device=out.leaf.device)
    return leaf_loss(out.leaf, is_leaf)


def _tree_loss(output: VAEOutput, tree, line_terms: tuple, node_terms, weights: Mapping[str, float],
               kl: bool) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The loss of a tree shared by :func:`program_loss` and :func:`macro_program_loss`: ``node_terms(node,
    out)`` (the line terms and ``leaf`` of one node) summed over the nodes, then ``bb``, ``kl`` and the total."""
    nodes = [n for n, _ in tree.nodes()]
    if len(nodes) != len(output.nodes):
        raise ValueError(f"the output has {len(output.nodes)} nodes, the tree {len(nodes)}")
    zero = output.bbox_dims.new_zeros(())
    terms = {k: zero for k in line_terms + ("leaf",)}
    for node, out in zip(nodes, output.nodes):
        for k, v in node_terms(node, out).items():
            terms[k] = terms[k] + v
    terms["bb"] = (output.bbox_dims - tree.bbox_dims).abs().sum()
    terms["kl"] = kl_loss(output.mu, output.logvar) if kl else zero
    total = sum((weights.get(k, 0.0) * v for k, v in terms.items()), zero)
    return total, terms


# ------------------------------------------------------------------------ macro programs (ShapeMOD)

#: The weight of each term of :func:`macro_program_loss` (the base model's: CE 1, L1 50, KL 0.1).
MACRO_LOSS_WEIGHTS = {"cmd": 1.0, "cube": 1.0, "float": 50.0, "face": 1.0, "axis": 1.0, "bool": 1.0, "leaf": 1.0,
                      "bb": 50.0, "kl": 0.1}
#: The terms of :func:`macro_line_losses`.
MACRO_LINE_TERMS = ("cmd", "cube", "float", "face", "axis", "bool")


def macro_line_losses(pred: torch.Tensor, target: torch.Tensor, layout) -> dict[str, torch.Tensor]:
    """The per-line terms of one node of a macro program, each masked by the *target* line's function.

    Args:
        pred: (T, width) float, predicted lines (logits for one-hots and booleans).
        target: (T, width) float, the target lines ``[l1 .. lL, stop]`` (row 0 the bbox line).
        layout: the :class:`~shapeprog.vae.layout.LineLayout`.

    Returns:
        Scalar sums named as :data:`MACRO_LINE_TERMS`: ``cmd`` CE over every row; ``cube``, ``face``, ``axis``
        CE on each slot the row's function uses; ``float`` L1 on each used float; ``bool`` BCE-with-logits on
        each used boolean of every row but the first (the bbox line's aligned flag is not learnt). A slot the
        function does not use contributes neither loss nor gradient.
    """
    if pred.dim() != 2 or pred.shape != target.shape or pred.shape[1] != layout.width:
        raise ValueError(f"pred and target must both be (T, {layout.width}), got {tuple(pred.shape)} and "
                         f"{tuple(target.shape)}")
    cmds = target[:, layout.slices["cmd"]].argmax(dim=1)
    zero = pred.new_zeros(())
    out = {"cmd": F.cross_entropy(pred[:, layout.slices["cmd"]], cmds, reduction="sum")}
    for t, name in (("cube", "cube"), ("face", "face"), ("axis", "axis")):
        if not layout.counts[t]:
            out[name] = zero
            continue
        used = layout.masks[t].to(pred.device)[cmds]  # (T, k)
        logits, want = layout.part(pred, t)[used], layout.part(target, t)[used]
        out[name] = F.cross_entropy(logits, want.argmax(-1), reduction="sum") if logits.numel() else zero
    if layout.counts["float"]:
        used = layout.masks["float"].to(pred.device)[cmds]
        out["float"] = (pred[:, layout.slices["float"]][used] - target[:, layout.slices["float"]][used]).abs().sum()
    else:
        out["float"] = zero
    if layout.counts["bool"]:
        used = layout.masks["bool"].to(pred.device)[cmds].clone()
        used[0] = False
        p, t_ = pred[:, layout.slices["bool"]][used], target[:, layout.slices["bool"]][used]
        out["bool"] = F.binary_cross_entropy_with_logits(p, t_, reduction="sum") if p.numel() else zero
    else:
        out["bool"] = zero
    return out


def macro_program_loss(output: VAEOutput, tree, layout, weights: Mapping[str, float] | None = None,
                       kl: bool = True) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The weighted training loss of one macro program (:meth:`shapeprog.vae.macro_model.MacroVAE.forward`
    of ``tree``, a :class:`~shapeprog.vae.layout.MacroNode`).

    Returns:
        ``(total, terms)``: the weighted sum and every unweighted term summed over the nodes
        (:data:`MACRO_LINE_TERMS`, ``leaf`` the mean BCE of each node's leaf logits per created cuboid,
        ``bb`` the L1 of the root bbox dims, ``kl``); weights default to :data:`MACRO_LOSS_WEIGHTS`.
    """
    def node_terms(node, out):
        return {**macro_line_losses(out.lines, node.target_seq(layout), layout),
                "leaf": _leaf_term(node, out, out.leaf.shape[0])}

    return _tree_loss(output, tree, MACRO_LINE_TERMS, node_terms, MACRO_LOSS_WEIGHTS if weights is None else weights,
                      kl)
