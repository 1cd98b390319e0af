"""What a round of candidate fits concludes when the time budget left some unfinished.

Once the time budget is spent a round's candidate fit is not started, or stopped at its next
iteration (:mod:`petsoft.diagnosis.budget`); its score entry then has no ``fit`` but
``unfinished`` (why). :func:`conclude` decides what the round may still conclude:

- An unfinished candidate is neither added nor rejected: how well it would predict the
  held-out window is not known, and a fit cut short keeps its chi2 only as an upper bound on
  what its converged fit reaches. Each is a report.json ``skipped`` entry (``round N:
  candidate fit of PHYSICS``) with what it risks, and a line of the log.
- The round adds the choice among its finished fits (:func:`~petsoft.diagnosis.selection.
  choose`) only when no unfinished candidate could have been chosen in its place: a finished
  fit that passes both tests predicts the held-out data to the noise and has fewer parameters
  than every unfinished candidate (:func:`~petsoft.diagnosis.selection.sufficient`: the rule
  by which :func:`~petsoft.diagnosis.selection.fit_simplest_first` leaves a batch unfitted).
  Which finished fit is chosen is decided among the finished ones: an unfinished fit that
  predicted better than all of them could only have narrowed the predictions counted as
  equally good to those within the noise (which matters only where another finished fit that
  passes both tests predicts the held-out data worse than the noise).
- Otherwise the round adds nothing and says so: its finished fits are judged (one failing a
  test is rejected as in any round), none is chosen, and a ``round N's choice`` entry names
  those that passed both tests and the unfinished ones that might have been preferred. The
  model stays the one the round started from; the budget being spent, no further round runs.
"""

from __future__ import annotations

from petsoft.diagnosis.selection import n_parameters, passes_both, sufficient


def conclude(diag, current, contenders: list, rnd: int) -> tuple[list, bool]:
    """The contenders ((score entry, candidate) pairs) the round may choose among, and
    whether it may choose at all (module docstring); the unfinished ones are recorded as
    left out (``diag.budget.skip``) and said. Without unfinished fits: ``(contenders, True)``.
    """
    unfinished = [(s, c) for s, c in contenders if s.unfinished]
    if not unfinished:
        return contenders, True
    finished = [(s, c) for s, c in contenders if not s.unfinished]
    fewest = min(n_parameters(c) for _, c in unfinished)
    decider = sufficient(diag, current, finished, fewest)
    for s, c in unfinished:
        said = f"{c.physics} (score S = {s.score:.4g}, p = {s.p_value:.3g}) was not judged"
        entry = diag.budget.skip(
            f"round {rnd}: candidate fit of {c.physics}",
            f"{said}: it might have been the round's choice, and the model may lack the "
            "physics it names" if decider is None else
            f"{said}: with {n_parameters(c)} parameters it could not have been preferred to "
            f"{decider[0].physics}, which predicts the held-out data to the noise with fewer, "
            "but whether it explains the data better is not known", detail=s.unfinished)
        diag.tell(f"time budget: round {rnd}'s candidate {c.physics} unfinished "
                  f"({entry['why']})")
    names = ", ".join(c.physics for _, c in unfinished)
    if decider is not None:
        diag.tell(f"round {rnd}: {decider[0].physics} decides the round without {names}: it "
                  "predicts the held-out data to the noise with fewer parameters than any of "
                  "them")
        return finished, True
    passers = [c.physics for s, c in finished if s.fit is not None
               and not s.fit.stopped and passes_both(diag, current, s.fit, c)]
    risk = ((f"{', '.join(passers)} passed both tests but" if passers else
             "no finished fit passed both tests, and") + f" {names}, unfinished, might have "
            "been preferred: no term was added, and the model may lack the physics one of "
            "them names")
    diag.budget.skip(f"round {rnd}'s choice", risk,
                     detail=f"{len(unfinished)} of its {len(contenders)} candidate fits "
                            "unfinished")
    diag.tell(f"round {rnd}: adds nothing: {risk}")
    return finished, False

