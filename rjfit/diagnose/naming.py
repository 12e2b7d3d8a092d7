"""When a decisive candidate is named (issue 26, item 3): evidence alone can be fooled by a
wrong model, so a candidate must also explain a stated share of what is missing, with
physical parameters, and the Mitsuba simulation must agree.

A candidate effect is NAMED at a step only when all of these hold:

1. it is decisive (:data:`rjfit.diagnose.candidates.DECISION_RULE`: log BF > ln 100 and
   delta ELPD_LOO > 4 SE);
2. it closes at least :data:`GAP_SHARE` of the current model's excess gap:
   (gap(current) - gap(with it)) / gap(current) >= 0.5, both with the search's noise estimate
   (a flexible effect such as light_calibration's L - 1 free gains absorbs a little of any
   structured misfit, decisively on a million observations, without explaining it);
3. its parameters are physical: no prior-data conflict
   (:func:`rjfit.diagnose.candidates.prior_conflicts`: none beyond 3 prior sd away from its
   null and from a physical end of its range, which is also where a parameter pinned at a
   bound of its support lies);
4. where the data set has a mesh (and the simulation is on), the Mitsuba simulation agrees:
   the simulated gap of the model with it (its scene change rendered by the path tracer) is
   below that of the current model: the closed form's improvement must be one the physics
   reproduces. The path tracer carries some effects by itself: the current model's render
   traces shadow rays, so on data with cast shadows its simulated gap is already ~0 and
   cannot fall (measured: 1.21 in closed form, -0.035 simulated, the same with cast_shadows
   added). So where the current model's simulated gap is below
   :data:`rjfit.diagnose.misfit.UNEXPLAINED_GAP`, the simulation also agrees when it stays
   below that with the effect and the closed-form gap moves toward the simulated one.
5. the current model leaves a misfit: its gap is above :data:`rjfit.diagnose.misfit.UNEXPLAINED_GAP`.
   Below it, rule 2's share is a ratio of two numbers within the gap's own error (the noise
   estimate's included), and a flexible effect "closes" any multiple of it: on the GGX roughplastic
   stack, after the coating, light_calibration was named on a gap of 0.001 ("1133 %",
   docs/results/2026-11-28-coating.md), and on the power-law camera stack ambient on 0.036 after
   camera_gamma (docs/results/2026-11-28-loop.md). A model within 0.1 is one the diagnosis calls
   adequate, so there is nothing left for an effect to explain.

Among the candidates that qualify, the largest log BF is named. When none qualifies and the
final gap is above :data:`rjfit.diagnose.misfit.UNEXPLAINED_GAP`, the diagnosis reports an
unexplained misfit and where it sits (:mod:`rjfit.diagnose.misfit`).
"""
from __future__ import annotations

from rjfit.diagnose.candidates import loo_support_text
from rjfit.diagnose.gap import gap
from rjfit.diagnose.misfit import UNEXPLAINED_GAP
from rjfit.diagnose.simulate import simulate_fit

__all__ = ["GAP_SHARE", "NAMING_RULE", "judge_candidates"]

GAP_SHARE = 0.5
NAMING_RULE = (f"named when the current model's gap is above {UNEXPLAINED_GAP:g} AND decisive AND it closes >= "
               f"{GAP_SHARE:.0%} of the current model's excess gap AND its "
               f"parameters are physical (no prior-data conflict) AND, with a mesh, the Mitsuba-simulated gap falls "
               f"too (or, where the path tracer already reproduces the data, stays below {UNEXPLAINED_GAP:g} while the "
               f"closed form moves toward it); among those the largest log BF")


def judge_candidates(ctx, rows, fits, candidate_residuals, current, residuals, sigma2, *, simulate, n_sim_draws,
                     seed) -> list:
    """Apply the rule to the decisive and the supported ``rows`` of one step (in place: ``gap_share``,
    ``physical``, the simulated gaps where rendered, ``qualifies``, ``why_not`` and ``short_of``: the rules
    it fails, of 'decisive' (1: a supported row, :mod:`rjfit.diagnose.candidates`), 'misfit' (5), 'gap_share' (2),
    'physical' (3), 'simulation' (4)); returns the rows that qualify. A supported row never qualifies; it is
    judged by the other rules so that it can be a trial (:mod:`rjfit.diagnose.pairs`).

    ``fits`` and ``candidate_residuals`` map an effect name to its refit and standardised
    residuals; ``residuals`` are the current model's; ``sigma2`` the search's noise estimate.
    The Mitsuba simulations run only for candidates that passed 1 to 3 (the current model's
    once per step).
    """
    gap_current = gap(residuals, sigma2)
    simulated_current = None
    qualified = []
    for row in rows:
        if not (row.get("decisive") or row.get("supported")):
            continue
        gap_with = gap(candidate_residuals[row["effect"]], sigma2)
        row["gap_share"] = (gap_current - gap_with) / gap_current if gap_current > 0 else 0.0
        row["physical"] = not row.get("prior_conflict")
        why, short_of = [], []
        if not row.get("decisive"):
            why.append(f"supported only (its LOO gain {loo_support_text(row)})")
            short_of.append("decisive")
        if gap_current <= UNEXPLAINED_GAP:
            why.append(f"the current model's gap {gap_current:.3g} is within {UNEXPLAINED_GAP:g}: no misfit left to "
                       "explain")
            short_of.append("misfit")
        elif row["gap_share"] < GAP_SHARE:
            why.append(f"closes {row['gap_share']:.0%} of the excess gap (< {GAP_SHARE:.0%})")
            short_of.append("gap_share")
        if not row["physical"]:
            why.append("a parameter in prior-data conflict")
            short_of.append("physical")
        if not why and simulate:
            if simulated_current is None:
                simulated_current = simulate_fit(ctx, current, sigma2, n_draws=n_sim_draws, seed=seed)["gap"]
            simulated = simulate_fit(ctx, fits[row["effect"]], sigma2, n_draws=n_sim_draws, seed=seed)["gap"]
            row["simulated_gap_current"], row["simulated_gap_with_effect"] = simulated_current, simulated
            if not simulated < simulated_current:
                if _simulation_carries_it(gap_current, gap_with, simulated_current, simulated):
                    row["simulation_carries_effect"] = True
                else:
                    why.append(f"the Mitsuba-simulated gap does not fall ({simulated_current:.3g} -> {simulated:.3g})")
                    short_of.append("simulation")
        row["qualifies"] = not why
        row["short_of"] = short_of
        if why:
            row["why_not"] = "; ".join(why)
        else:
            qualified.append(row)
    return qualified


def _simulation_carries_it(gap_current, gap_with, simulated_current, simulated) -> bool:
    """Rule 4's second branch: the current model's render already reproduces the data (the path
    tracer carries the effect by itself), stays so with the effect, and the closed form moves toward it."""
    return (simulated_current < UNEXPLAINED_GAP and simulated < UNEXPLAINED_GAP
            and abs(gap_with - simulated) < abs(gap_current - simulated_current))
