"""The study's web app: pages, a JSON API and one WebSocket per ride (FastAPI).

    app = create_app(settings, StudyDatabase("study.sqlite"), admin_token)
    uvicorn.run(app, host="127.0.0.1", port=8765, ws_max_size=MAX_MESSAGE_BYTES)

Routes: ``/`` (the single page, `static/index.html`), ``/static/...``;
``GET /api/study`` (questions, labels, limits), ``GET /api/roads`` (lane
shapes); ``POST /api/participants`` (consent: a random id and the ride order),
``.../{id}/demographics``, ``.../{id}/answers`` (one transaction each),
``.../{id}/finish``; ``POST /api/rides`` (a ride process, or 503 with the
busy message); ``WS /ws/rides/{ride_id}?token=...``; ``GET /admin/report``
and ``GET /admin/export/{table}.csv`` with the admin token (``Authorization:
Bearer`` or ``?token=``). Request bodies are checked by pydantic models that
refuse unknown fields; WebSocket messages by `jaxround.study.protocol`.
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import io
import secrets
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Literal

from fastapi import Depends, FastAPI, HTTPException, Query, Request, WebSocket
from fastapi import Path as PathParam
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field

from jaxround.scenario.config import load_config
from jaxround.study.limits import BodyLimit, validation_error
from jaxround.study.logs import AccessLog, log_event
from jaxround.study.pedals import read_pedal_map
from jaxround.study.questions import ORDERS, QUESTION_IDS, ride_label, worded_questions
from jaxround.study.relay import CLOSE_TAKEN, CLOSE_UNKNOWN, refuse, relay
from jaxround.study.rides import BusyError, RideManager
from jaxround.study.roads import scenario_roads
from jaxround.study.settings import StudySettings, leg_index
from jaxround.study.sim import RideSpec
from jaxround.study.storage import (
    COLUMNS,
    AnswerExistsError,
    NotYetError,
    StudyDatabase,
    UnknownParticipantError,
)

STATIC = Path(__file__).parent / "static"
ParticipantId = Annotated[str, PathParam(pattern=r"^[A-Za-z0-9_-]{8,64}$")]


class Strict(BaseModel):
    """A request body: no unknown fields, no conversions ("2" is not 2)."""

    model_config = ConfigDict(extra="forbid", strict=True)


class Consent(Strict):
    consent: Literal[True]


class Demographics(Strict):
    gender: Literal["female", "male", "other", "not_said"] | None = None
    age: int | None = Field(default=None, ge=16, le=120)
    driving_years: int | None = Field(default=None, ge=0, le=100)


class Answer(Strict):
    question: Literal[QUESTION_IDS]  # type: ignore[valid-type]
    option: int = Field(ge=0, le=4)


class RideRequest(Strict):
    participant_id: str = Field(pattern=r"^[A-Za-z0-9_-]{8,64}$")
    kind: Literal["practice", "first", "second"]


def create_app(
    settings: StudySettings, database: StudyDatabase, admin_token: str
) -> FastAPI:
    """The app of one study; `settings` must have been validated."""
    cfg = load_config(settings.config)
    roads = scenario_roads(cfg)
    manager = RideManager(settings, database, str(settings.policy))
    origin = leg_index(cfg, settings.ego_origin)
    destination = leg_index(cfg, settings.ego_destination)
    pedal_map = read_pedal_map(settings.pedal_map) if settings.pedal_map else {}

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        yield
        await manager.shutdown()

    app = FastAPI(
        title="jaxround study",
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
        openapi_url=None,
    )
    app.state.manager = manager
    app.state.database = database
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_middleware(BodyLimit)
    app.add_middleware(AccessLog)  # outermost: sees the 413s too
    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    def participant(participant_id: str) -> dict:
        try:
            return database.participant(participant_id)
        except UnknownParticipantError:
            raise HTTPException(404, "no participant has this id") from None

    def admin(request: Request, token: str | None = Query(default=None)) -> None:
        header = request.headers.get("authorization", "")
        given = header.removeprefix("Bearer ").strip() if header else token
        if not given or not secrets.compare_digest(given, admin_token):
            raise HTTPException(401, "the admin token printed at start is needed")

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(STATIC / "index.html")

    @app.get("/api/study")
    def study() -> dict:
        return {
            "blind": settings.blind,
            "questions": worded_questions(settings.blind),
            "max_participants": settings.max_participants,
            "places_free": manager.places_free,
            "ride_s": settings.ride_s,
            "practice_s": settings.practice_s,
            "passes": settings.passes,
            "practice_passes": settings.practice_passes,
            "estimate_min": settings.estimated_minutes(),
            "step_s": settings.step_s,
            "pedal_map": pedal_map,
            "lane_changes": not cfg.network.single_lane,
        }

    @app.get("/api/roads")
    def road_shapes() -> dict:
        return roads

    @app.post("/api/participants", status_code=201)
    def add_participant(body: Consent) -> dict:
        participant_id, order = database.add_participant(settings.blind)
        log_event("participant_added", participant=participant_id, order=order)
        shares = ORDERS[order]
        return {
            "participant_id": participant_id,
            "order": order,
            "labels": {
                kind: ride_label(share, i, settings.blind)
                for i, (kind, share) in enumerate(zip(("first", "second"), shares))
            },
        }

    @app.post("/api/participants/{participant_id}/demographics")
    def demographics(participant_id: ParticipantId, body: Demographics) -> dict:
        try:
            database.set_demographics(
                participant_id, body.gender, body.age, body.driving_years
            )
        except UnknownParticipantError:
            raise HTTPException(404, "no participant has this id") from None
        log_event("demographics_stored", participant=participant_id)
        return {"stored": True}

    @app.post("/api/participants/{participant_id}/answers", status_code=201)
    def answer(participant_id: ParticipantId, body: Answer) -> dict:
        try:
            database.add_answer(participant_id, body.question, body.option)
        except UnknownParticipantError:
            raise HTTPException(404, "no participant has this id") from None
        except (AnswerExistsError, NotYetError) as err:
            log_event("answer_refused", participant=participant_id, reason=str(err))
            raise HTTPException(409, str(err)) from None
        log_event("answer_stored", participant=participant_id, question=body.question)
        return {"stored": True}

    @app.post("/api/participants/{participant_id}/finish")
    def finish(participant_id: ParticipantId) -> dict:
        try:
            database.finish(participant_id)
        except UnknownParticipantError:
            raise HTTPException(404, "no participant has this id") from None
        except NotYetError as err:
            raise HTTPException(409, str(err)) from None
        log_event("participant_finished", participant=participant_id)
        return {"stored": True}

    @app.post("/api/rides", status_code=201)
    async def start_ride(body: RideRequest) -> JSONResponse:
        who = await asyncio.to_thread(participant, body.participant_id)
        if body.kind == "practice":
            share, label = None, "practice ride"
            ride_s, warmup_s, passes = (
                settings.practice_s,
                0.0,
                settings.practice_passes,
            )
        else:
            position = 0 if body.kind == "first" else 1
            share = ORDERS[who["ride_order"]][position]
            label = ride_label(share, position, bool(who["blind"]))
            ride_s, warmup_s, passes = (
                settings.ride_s,
                settings.warmup_s,
                settings.passes,
            )
        spec = RideSpec(
            ride_id=secrets.token_urlsafe(12),
            config=settings.config,
            share=share,
            policy=str(settings.policy),
            seed=settings.schedule_seed(cfg),
            warmup_s=warmup_s,
            ride_s=ride_s,
            step_s=settings.step_s,
            ego_origin=origin,
            ego_destination=destination,
            passes=passes,
        )
        try:
            ride = await manager.start(spec, body.participant_id, body.kind, label)
        except BusyError as err:
            log_event("ride_refused_busy", participant=body.participant_id,
                      kind=body.kind)  # fmt: skip
            return JSONResponse({"busy": True, "detail": str(err)}, status_code=503)
        return JSONResponse(
            {
                "ride_id": ride.ride_id,
                "token": ride.token,
                "label": label,
                "ride_s": ride_s,
                "passes": passes,
            },
            status_code=201,
        )

    @app.websocket("/ws/rides/{ride_id}")
    async def ride_socket(websocket: WebSocket, ride_id: str, token: str = "") -> None:
        await websocket.accept()
        ride = manager.rides.get(ride_id)
        if ride is None or not secrets.compare_digest(token, ride.token):
            await refuse(websocket, CLOSE_UNKNOWN, "no ride with this id and token")
            return
        if ride.connected:
            await refuse(
                websocket, CLOSE_TAKEN, "this ride is open in another window already"
            )
            return
        ride.connected = True
        await relay(websocket, manager, ride)

    @app.get("/admin/report")
    def admin_report(_: None = Depends(admin)) -> dict:
        from jaxround.study.report import build_report

        return build_report(database)

    @app.get("/admin/export/{table}.csv")
    def admin_export(table: str, _: None = Depends(admin)) -> PlainTextResponse:
        if table not in COLUMNS:
            raise HTTPException(
                404, f"table {table!r}, expected one of {sorted(COLUMNS)}"
            )
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=COLUMNS[table])
        writer.writeheader()
        writer.writerows(database.rows(table))
        return PlainTextResponse(buffer.getvalue(), media_type="text/csv")

    return app
