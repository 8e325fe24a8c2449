"""The command line's side of publishing a result (``ucal.fleet.publish``).

``prepare_publication`` runs with the procedure, before anything moves: a cell that cannot be
named in a topic is refused there (exit 2). ``publish_outcome`` runs once the result is final,
whatever it is (in tolerance, out of tolerance, standing after a late signal): one line says
where the result went, a warning where it was queued instead; nothing it meets changes the
run's outcome or exit code. A dry run and a replay write nothing, so they publish nothing.
"""

from __future__ import annotations

import logging
from typing import Any

import click

from ucal import interrupt
from ucal.cli.options import info, publish_url, warn
from ucal.errors import EXIT_INTERRUPTED, EXIT_OK, EXIT_OUT_OF_TOLERANCE
from ucal.fleet.message import Finished
from ucal.fleet.publish import Publication, prepare, publish
from ucal.procedure import Job, Outcome, RunOptions

log = logging.getLogger(__name__)

#: Where the prepared publication waits for the result, in the command's context.
_KEY = "ucal.publication"


def prepare_publication(job: Job[Any, Any, Any, Any], options: RunOptions) -> None:
    """With ``--publish``, check that the run's result can be published, before the run."""
    ctx = click.get_current_context(silent=True)
    url = publish_url(ctx)
    if ctx is None or url is None:
        return
    if not options.writes:
        what = "a replay" if options.replay is not None else "a dry run"
        warn(f"{what} writes nothing: its result is not published to {url}")
        return
    simulated = options.cell is not None and options.cell.sim_world is not None
    ctx.meta[_KEY] = (prepare(url, job.profile_path), simulated)


def publish_outcome(outcome: Outcome[Any], message: str | None) -> None:
    """Publish ``outcome`` if the run was prepared to (``message``: the one-line error of a
    result out of tolerance or interrupted, None in tolerance)."""
    ctx = click.get_current_context(silent=True)
    prepared = None if ctx is None else ctx.meta.pop(_KEY, None)
    if prepared is None:
        return
    publication, simulated = prepared
    code = (
        EXIT_INTERRUPTED
        if interrupt.received
        else EXIT_OUT_OF_TOLERANCE
        if outcome.out_of_tolerance
        else EXIT_OK
    )
    done = Finished(
        command=outcome.command,
        exit_code=code,
        message=message or "",
        result=outcome.to_json(),
        written=outcome.written,
        out_of_tolerance=outcome.out_of_tolerance,
        simulated=simulated,
    )
    try:
        _publish(publication, done)
    except Exception as e:  # publishing never changes the run's result
        log.debug("publishing failed", exc_info=True)
        warn(f"the {done.command} result was not published ({type(e).__name__}: {e})")


def _publish(publication: Publication, done: Finished) -> None:
    url, cell = publication.url, publication.cell.name
    delivery = publish(publication, done, deliver=done.exit_code != EXIT_INTERRUPTED)
    if delivery.queued is None:
        warn(f"the {done.command} result was not published to {url}: {delivery.error}")
    elif delivery.complete:
        before = delivery.delivered - 1
        earlier = f", after {before} queued before it" if before > 0 else ""
        info(f"published the {done.command} result to {url.result_topic(cell)}{earlier}")
    else:
        why = "interrupted: not sent" if delivery.error == "not sent" else delivery.error
        warn(
            f"the {done.command} result is queued in {delivery.outbox} ({delivery.waiting} "
            f"waiting; {why}): the next run that publishes for cell {cell} sends them in order"
        )
