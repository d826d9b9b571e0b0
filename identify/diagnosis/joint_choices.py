"""What the joint diagnosis fits (:mod:`identify.diagnosis.joint`): pure choices from the
records' own searches and the joint fits made so far.

* :func:`explanations_worth_finishing` - the explanations any record's own search found worth
  finishing, fitted on every record together;
* :func:`short_ends_to_finish` - which ends of an explanation's short joint refits its fit is
  finished from;
* :func:`rival_pair_names` - the pairs to fit before a member of the best pair is named;
* :func:`tie_member_pairs` - the pairs of a tie's members to fit before the tie is the verdict.
"""

from __future__ import annotations

from .adequacy import Thresholds

__all__ = ["explanations_worth_finishing", "rival_pair_names", "short_ends_to_finish", "tie_member_pairs"]


def explanations_worth_finishing(alone, thresholds: Thresholds) -> list[str]:
    """The explanations any record found worth finishing: those that repair it and the
    ``max_refits`` best by their gain, singles and pairs; a pair once, in the order of the first
    record that names it (a model's effects are a set: ``"a+b"`` and ``"b+a"`` are one fit)."""
    names = {}
    for d in alone:
        singles = [c for c in d.ranking if c.refitted and c.fit is not None]
        pairs = [c for c in d.pairs_tried if c.fit is not None]
        for group in (singles, pairs):
            ranked = sorted(group, key=lambda c: -c.delta_bic)
            keep = [c for c in ranked if c.adequate_after] + ranked[: thresholds.max_refits]
            for c in keep:
                if c.delta_bic > 0.0:
                    names.setdefault(frozenset(c.effect.split("+")), c.effect)
    return list(names.values())


def short_ends_to_finish(best_chi2: float | None, short_ends) -> list:
    """The joint vectors of ``short_ends`` (``[(chi2, joint vector)]``: where an explanation's
    short joint refits ended) from which its fit is finished: each one where no other start
    was run (``best_chi2`` None), otherwise those whose short run already lies below
    ``best_chi2``, the lowest of the other starts' finished fits. A fit never ends above a short
    run of itself already made."""
    return [start for chi2, start in short_ends if best_chi2 is None or chi2 < best_chi2]


def rival_pair_names(strength: dict, max_refits: int) -> list[tuple[str, str, str]]:
    """The pairs to fit before a member of the best pair may be named: the pairs that would name
    another effect, not fitted yet, strongest first, at most ``max_refits`` per member.

    The best pair names its member stronger alone. A pair that keeps its partner and swaps the
    named member for any single with a gain names another effect whichever of the two is stronger;
    a pair that keeps the named member and swaps its partner for a single names another effect only
    when that single is at least as strong alone. No bound on what a pair can gain from its members
    alone stands in for fitting it: explanations overlap (a run's drift takes up part of a heating
    and part of a first-cycle offset), so a pair of two that do not can gain far more than either
    member's gain suggests. The rule of :func:`identify.diagnosis.pairs.rival_pairs`, which the
    records' own searches use, without its bound on the pair's gain.

    Parameters
    ----------
    strength : dict
        ``{explanation: delta BIC}`` of every joint fit, singles and pairs (``"a+b"``); a member
        of the best pair that is not among them (no record found it worth finishing alone)
        counts as gaining nothing alone.
    max_refits : int

    Returns
    -------
    list of (str, str, str)
        Each new pair's name (the swapped-in single in the member's place), the best pair's name
        and the swapped-in single's.
    """
    pairs = {n: v for n, v in strength.items() if "+" in n}
    if not pairs:
        return []
    best = max(pairs, key=pairs.get)
    fitted = {frozenset(n.split("+")) for n in pairs}
    members = best.split("+")
    # a member no record found worth finishing alone was not fitted jointly: it gains nothing
    alone = [strength.get(m, 0.0) for m in members]
    named = 0 if alone[0] >= alone[1] else 1
    names = []
    for position in range(2):  # the member swapped out
        partner = members[1 - position]
        bar = 0.0 if position == named else alone[named]
        rivals = sorted(
            (n for n, v in strength.items() if "+" not in n and n not in members and v > 0 and v >= bar),
            key=lambda n: -strength[n],
        )
        taken = 0
        for rival in rivals:
            if frozenset((rival, partner)) in fitted or taken >= max_refits:
                continue
            pair = [rival, partner] if position == 0 else [partner, rival]
            names.append(("+".join(pair), best, rival))
            fitted.add(frozenset(pair))
            taken += 1
    return names


def tie_member_pairs(tied, strength: dict) -> list[tuple[str, tuple | None]]:
    """The pairs of a tie's members not fitted yet, to fit before the tie is the verdict, each
    with the fits to start it from.

    A tie lists what the records cannot tell apart; when it holds pairs, their members can also
    combine otherwise (a heating tied in one pair, a first-cycle strain in another), and the
    records may prefer such a recombination to every pair listed. A tie is a verdict only once
    every pair of its members has been fitted.

    Parameters
    ----------
    tied : sequence of str
        The tied explanations (singles and pairs ``"a+b"``).
    strength : dict
        ``{explanation: delta BIC}`` of every joint fit made, singles and pairs.

    Returns
    -------
    list of (str, tuple or None)
        Each new pair's name (its members in the order of the strongest tied explanation that
        holds them) and ``(pair, single)``: the strongest fitted pair that holds one member but
        not the other, and the other member's single (fitted), to start it from (None where no
        such two exist); strongest members first.
    """
    members = list(dict.fromkeys(m for name in tied for m in name.split("+")))
    if not any("+" in name for name in tied) or len(members) < 3:
        return []
    fitted = {frozenset(n.split("+")) for n in strength}
    pairs = {n: v for n, v in strength.items() if "+" in n}
    found = []
    for i, a in enumerate(members):
        for b in members[i + 1 :]:
            if frozenset((a, b)) in fitted:
                continue
            swap = None
            for keep, single in ((b, a), (a, b)):  # a pair holding one member, the other's single
                holders = [n for n in pairs if keep in n.split("+") and single not in n.split("+")]
                if holders and single in strength:
                    best = max(holders, key=pairs.get)
                    if swap is None or pairs[best] > pairs[swap[0]]:
                        swap = (best, single)
            found.append((f"{a}+{b}", swap))
    found.sort(key=lambda item: -sum(strength.get(m, 0.0) for m in item[0].split("+")))
    return found
