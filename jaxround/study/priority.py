"""Scheduling priority for the processes whose delay the participant feels.

A ride's step and the server's relay of its frame wake up every 0.1 s for
about a millisecond. On a machine where other programs keep the cores busy,
a woken process may wait for a core behind them; the ride's frame is then
late. Where the system allows it, these processes are put ahead of ordinary
ones:

1. a real-time policy (``SCHED_RR``; Linux with ``CAP_SYS_NICE`` or an
   ``rtprio`` limit above 0, e.g. ``@study - rtprio 20`` in
   ``/etc/security/limits.conf``). The ride asks for `RIDE_RT_PRIORITY`, the
   server for `SERVER_RT_PRIORITY`: a ride's step comes before the server's
   other work (storing a ride that ended, pages). The kernel keeps 5% of
   each second for ordinary processes (``sched_rt_runtime_us``);
2. else a lower nice value (`NICE`), allowed to root only;
3. else nothing: the process stays as it was, and the log says so.

A ride asks only once its warm-up is over: the warm-up runs as fast as SUMO
goes and must not take a core from the others.
"""

from __future__ import annotations

import os

#: Real-time priorities (1-99): a ride's step above the server's relay.
RIDE_RT_PRIORITY = 20
SERVER_RT_PRIORITY = 10
#: The nice value asked for where real time is not allowed.
NICE = -10


def raise_priority(rt_priority: int) -> str:
    """Put the calling thread ahead of ordinary processes, as far as the
    system allows. Real time is not passed on (``SCHED_RESET_ON_FORK``): the
    threads and processes it starts later (a ride's warm-up, the server's
    database thread) are ordinary ones; a nice value is passed on.

    Returns:
        what was obtained, for the log: 'SCHED_RR 20', 'nice -10' or
        'unchanged (...)'.
    """
    if hasattr(os, "sched_setscheduler"):
        try:
            policy = os.SCHED_RR | getattr(os, "SCHED_RESET_ON_FORK", 0)
            os.sched_setscheduler(0, policy, os.sched_param(rt_priority))
            return f"SCHED_RR {rt_priority}"
        except (PermissionError, OSError):
            pass
    try:
        now = os.nice(0)
        if now > NICE:
            os.nice(NICE - now)
        return f"nice {os.nice(0)}"
    except (PermissionError, OSError) as err:
        return f"unchanged ({err.strerror or err})"
