"""The paper's human-in-the-loop study in a browser.

A participant gives consent, may give the demographics the paper reports,
drives a practice ride without traffic, then two rides through the live
roundabout among SUMO traffic in which an exported policy drives the AVs
(20% and 80% of the vehicles, order counterbalanced), and answers the
paper's three questions (its Tables 5, 6 and 7).

Modules:

- `settings`: what a study is run with (`StudySettings`), validated first.
- `questions`: the questionnaire worded as in the paper, blind labels, the
  paper's own counts.
- `sim`: one ride in SUMO through libsumo: background traffic, the policy,
  the ego vehicle driven by the participant's pedals.
- `telemetry`: a ride's trace summed up (gaps, time to collision, hard
  brakings, collisions, crossing time, delays).
- `worker`: the process that runs one ride in real time, talking to the
  server over a pipe.
- `rides`: the server's side of the rides: processes, the participant
  limit, relaying frames, reaping.
- `roads`: the lane shapes of the ``.net.xml`` for the browser's 3D view.
- `storage`: the SQLite database (schema in its docstring) and CSV export.
- `server`: the FastAPI app (pages, JSON API, one WebSocket per ride).
- `report`: Tables 5-7 with the paper's counts, sign tests, telemetry.
- `load`: scripted riders over loopback, for the server's delay figures.
- `cli`: ``jaxround study serve|export|report|load``.
"""
