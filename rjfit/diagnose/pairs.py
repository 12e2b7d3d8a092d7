"""Pairs of effects, and the effect a refit of the regions should try (issue 45).

The search names one effect at a time on a fixed segmentation. Where the data miss two effects
together, each alone can fail the naming rule (:mod:`rjfit.diagnose.naming`): on Mitsuba's GGX
lobe under a dielectric coating, fitted under the material model, the GGX lobe alone closed 20 %
of the gap and the coating alone pulled its index to the prior's floor (a conflict), while the
two together had physical parameters (w 0.97 and 0.97, index 1.64 for 1, 1, 1.5) and a log BF of
2,330 (docs/results/2026-11-29-trials.md). So where no single candidate qualifies, the pairs of
the decisive ones (of different kinds, the :data:`PAIR_FROM` with the largest log BF) are refitted
and judged by the same rule.

A fixed segmentation can also hide what an effect explains: a plain fit splits materials to
absorb a misfit, and with the right effects those split-off regions no longer fit (the same
stack: the pair brought 86 % of the observations to the noise level, yet the split-off 14 %
took the whole gap up, a share of -82 %). Such a candidate, decisive and physical and short of
the naming rule's gap share only, is the diagnosis' ``trial``: ``rjfit refine`` fits again with it
sampled with the regions and keeps it only when the gap on the new segmentation is at most half
the old one (:mod:`rjfit.pipeline.refine_trial`). The extra regions can absorb so much that the gap left
is within the naming rule's floor (rule 5): on Mitsuba's GGX roughplastic with a roughness per material, 7
regions for 4 left 0.099 while fresnel was decisive (log BF 80). A decisive, physical candidate short of that
rule is a trial too, which the loop keeps only where its fit needs fewer regions. A supported candidate (its
log BF decisive and its LOO gain positive where PSIS is reliable: :mod:`rjfit.diagnose.candidates`) that fails no
other rule but these is a trial after every decisive one: the regions that absorbed a misfit make the LOO's SE
noise. The diagnosis itself names single effects only.
"""
from __future__ import annotations

from itertools import combinations

from rjfit.diagnose.candidates import judged_fields, refit_threads
from rjfit.diagnose.loo import loo_difference
from rjfit.diagnose.naming import judge_candidates
from rjfit.diagnose.refit import refit, standardised_residuals
from rjfit.effects import get_effect

__all__ = ["PAIR_FROM", "TRIAL_MAY_FAIL", "SUPPORTED_MAY_FAIL", "score_pairs", "step_trials", "trial_candidates"]

#: the decisive single candidates (largest log BF first) whose pairs are refitted: at most 3 pairs
PAIR_FROM = 3
#: the rules a trial candidate may fail: the gap share on the fixed segmentation (rule 2), which a
#: refit of the regions measures again, and the misfit left (rule 5): a segmentation whose extra regions absorbed
#: the misfit has little gap left for any effect to explain, and a refit that lets them merge shows it
#: (:func:`rjfit.pipeline.refine_trial.judge_trial` judges such a trial by its regions)
TRIAL_MAY_FAIL = {"gap_share", "misfit"}
#: the LOO figures a supported trial carries
LOO_FIELDS = ("delta_elpd_loo", "delta_elpd_loo_se", "delta_elpd_loo_reliable", "delta_elpd_loo_reliable_se")
#: the rules a supported (not decisive) trial candidate may fail: those, and the decision rule's LOO bar
SUPPORTED_MAY_FAIL = TRIAL_MAY_FAIL | {"decisive"}


def score_pairs(ctx, step, current, decisive_rows, fits, residuals, sigma2, settings) -> list:
    """Refit ``current`` plus each pair of the decisive single candidates ``decisive_rows`` (their refits
    ``fits`` by name) and judge it as a single one is judged; returns the pairs' rows (empty for fewer than two
    decisive candidates of different kinds). ``settings``: the search's
    (:class:`rjfit.diagnose.workflow.SearchSettings`)."""
    ranked = sorted(decisive_rows, key=lambda row: row["log_bayes_factor"], reverse=True)[:PAIR_FROM]
    # same kind: both explain one part (revisit.py)
    pairs = [(a["effect"], b["effect"]) for a, b in combinations(ranked, 2) if a["kind"] != b["kind"]]
    rows, pair_fits, pair_residuals = [], {}, {}
    for names, candidate in zip(pairs, _refit_pairs(ctx, current, pairs, fits, settings)):
        loo = (loo_difference(candidate, current)
               if candidate.log_evidence - current.log_evidence > settings.threshold else None)
        row = {"step": step, "effect": "+".join(names), "effects": list(names), "kind": "pair"}
        row.update(judged_fields(candidate, current, names, loo, settings.threshold, settings.loo_se_factor))
        pair_fits[row["effect"]], pair_residuals[row["effect"]] = candidate, standardised_residuals(ctx, candidate)
        rows.append(row)
        settings.say(f"  pair {row['effect']:25s} log BF {row['log_bayes_factor']:10.1f}"
                     + ("  decisive" if row["decisive"] else ""))
    decisive = [row for row in rows if row["decisive"]]
    judge_candidates(ctx, decisive, pair_fits, pair_residuals, current, residuals, sigma2,
                     simulate=settings.simulates(ctx),
                     n_sim_draws=settings.n_sim_draws, seed=settings.seed)
    return rows


def step_trials(ctx, step_of, refits, residuals, sigma2, settings) -> tuple:
    """Where no candidate of a step qualified: ``(its pairs' rows (:func:`score_pairs`), its trials
    (:func:`trial_candidates`))``, its supported rows judged on the way (:func:`rjfit.diagnose.naming.judge_candidates`,
    in place). ``step_of``: (the step, the current model, the step's rows; their decisive rows judged already);
    ``refits``: the candidates' refits and standardised residuals by name; ``residuals`` the current model's."""
    step, current, rows = step_of
    fits, candidate_residuals = refits
    decisive = [row for row in rows if row.get("decisive")]
    supported = [row for row in rows if row.get("supported") and not row.get("decisive")]
    pairs = score_pairs(ctx, step, current, decisive, fits, residuals, sigma2, settings)
    judge_candidates(ctx, supported, fits, candidate_residuals, current, residuals, sigma2,
                     simulate=settings.simulates(ctx), n_sim_draws=settings.n_sim_draws, seed=settings.seed)
    return pairs, trial_candidates(decisive + pairs + supported)


def _refit_pairs(ctx, current, pairs, fits, settings) -> list:
    """``current`` refitted plus each pair of effect names, ``settings.jobs`` at a time on threads (as the single
    candidates are: :func:`rjfit.diagnose.candidates.refit_threads`), each from the first effect's refit; in the
    pairs' order. Their Mitsuba features are in ``ctx`` already (the single candidates rendered them)."""
    def one(names):
        effects = tuple(current.effects) + tuple(get_effect(name) for name in names)
        return refit(ctx, effects, start=fits[names[0]], seed=settings.seed)

    if not pairs:
        return []
    with refit_threads(settings.jobs, len(pairs)) as pool:
        return list(pool.map(one, pairs))


def trial_candidates(rows) -> list:
    """The candidates (single or pair) a refit of the regions may try, best first: among ``rows`` (one step's,
    judged), the decisive ones that fail no rule but the gap share on the fixed segmentation or the misfit left
    (:data:`TRIAL_MAY_FAIL`), by log BF, then the supported ones that fail no rule but those and the decision rule's
    LOO bar (:data:`SUPPORTED_MAY_FAIL`), by log BF; each ``{"effects", "log_bayes_factor", "gap_share", "step",
    "within_floor", "decisive"}`` (``within_floor``: the current model's gap was within
    :data:`rjfit.diagnose.misfit.UNEXPLAINED_GAP`), a supported one with its LOO figures
    (:data:`LOO_FIELDS`). The first is the diagnosis' ``trial``; ``rjfit refine`` fits the next where a trial is
    not kept."""
    def eligible(row, decisive, may_fail):
        # a row neither decisive nor supported was not judged for a trial, whatever it holds
        judged = row.get("decisive") if decisive else row.get("supported") and not row.get("decisive")
        return bool(judged) and "short_of" in row and set(row["short_of"]) <= may_fail

    def trial(row):
        entry = {"effects": list(row.get("effects") or [row["effect"]]), "log_bayes_factor": row["log_bayes_factor"],
                 "gap_share": row["gap_share"], "step": row["step"], "within_floor": "misfit" in row["short_of"],
                 "decisive": bool(row.get("decisive"))}
        if not entry["decisive"]:
            entry.update({key: row[key] for key in LOO_FIELDS})
        return entry

    by_evidence = sorted(rows, key=lambda row: -row["log_bayes_factor"])
    return ([trial(row) for row in by_evidence if eligible(row, True, TRIAL_MAY_FAIL)]
            + [trial(row) for row in by_evidence if eligible(row, False, SUPPORTED_MAY_FAIL)])
