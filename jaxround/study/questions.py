"""The paper's three questions with their five answers each (Tables 5, 6, 7).

Options are kept in the paper's order: 0 and 1 favour the 20% ride
(definitely, partially), 2 and 3 favour the 80% ride (partially,
definitely), 4 is "no difference" (smoothness, safety) or "cannot say"
(preference). In a blind study the rides are called A (the first driven)
and B; the options are worded with A in place of the 20% ride, and an
answer is mapped back to the paper's option by the participant's order
(`paper_option`).
"""

from __future__ import annotations

from dataclasses import dataclass

from jaxround.study.settings import HIGH_SHARE, LOW_SHARE, share_label

#: Question ids, in the order asked (Tables 5, 6, 7).
QUESTION_IDS = ("smoothness", "safety", "preference")
#: Options per question.
N_OPTIONS = 5
#: Options that favour the high (80%) share, the low (20%) share, neither.
FAVOUR_HIGH = (2, 3)
FAVOUR_LOW = (0, 1)
NEUTRAL = (4,)
#: Answers per option in the paper (10 participants), Tables 5, 6, 7.
PAPER_COUNTS = {
    "smoothness": (1, 3, 4, 1, 1),
    "safety": (0, 2, 2, 6, 0),
    "preference": (0, 3, 3, 4, 0),
}
#: The paper's table number of each question.
PAPER_TABLE = {"smoothness": 5, "safety": 6, "preference": 7}
#: Ride orders: the AV share of the first and of the second ride.
ORDERS = {"20-80": (LOW_SHARE, HIGH_SHARE), "80-20": (HIGH_SHARE, LOW_SHARE)}


@dataclass(frozen=True)
class Question:
    """One question: its heading and option templates.

    The templates name the 20% ride ``{low}`` and the 80% ride ``{high}``
    (``{low_short}`` and ``{high_short}`` where the paper drops the "of").
    """

    id: str
    heading: str
    options: tuple[str, ...]


def _comparison(better: str, worse: str) -> tuple[str, ...]:
    return (
        f"Traffic in {{low}} was definitely {better} than in {{high_short}}",
        f"Traffic in {{low}} was partially {better} than in {{high_short}}",
        f"Traffic in {{low}} was partially {worse} than in {{high_short}}",
        f"Traffic in {{low}} was definitely {worse} than in {{high_short}}",
        "I did not perceive differences",
    )


QUESTIONS = (
    Question(
        "smoothness",
        "Regarding traffic smoothness, which of the following statements do you "
        "agree with the most?",
        _comparison("smoother", "less smooth"),
    ),
    Question(
        "safety",
        "Regarding safety perception, which of the following statements do you "
        "agree with the most?",
        _comparison("safer", "less safe"),
    ),
    Question(
        "preference",
        "Globally, which of the two scenarios did you prefer?",
        (
            "I definitely preferred {low_short} with respect to {high_short}",
            "I partially preferred {low_short} with respect to {high_short}",
            "I partially preferred {high_short} with respect to {low_short}",
            "I definitely preferred {high_short} with respect to {low_short}",
            "I cannot say which scenario I preferred",
        ),
    ),
)
QUESTION_BY_ID = {q.id: q for q in QUESTIONS}


def ride_names(blind: bool) -> dict[str, str]:
    """How the options name the two rides: the paper's words, or A and B."""
    if blind:
        return {
            "low": "ride A",
            "high": "ride B",
            "low_short": "ride A",
            "high_short": "ride B",
        }
    low, high = share_label(LOW_SHARE), share_label(HIGH_SHARE)
    return {
        "low": f"the scenario with {low} of AVs",
        "high": f"the scenario with {high} of AVs",
        "low_short": f"the scenario with {low} AVs",
        "high_short": f"the scenario with {high} AVs",
    }


def worded_questions(blind: bool) -> list[dict[str, object]]:
    """The questions as the participant reads them (plain data for the page)."""
    names = ride_names(blind)
    return [
        {
            "id": q.id,
            "heading": q.heading,
            "options": [o.format(**names) for o in q.options],
        }
        for q in QUESTIONS
    ]


def ride_label(share: float, position: int, blind: bool) -> str:
    """What a ride is called on the page: 'ride A' or the share it has.

    Args:
        share: the ride's AV share.
        position: 0 for the first ride, 1 for the second.
        blind: name the ride by its position only.
    """
    if blind:
        return "ride A" if position == 0 else "ride B"
    return f"the scenario with {share_label(share)} of AVs"


def paper_option(option_shown: int, order: str, blind: bool) -> int:
    """The paper's option for an answer as the participant chose it.

    Unblinded, the options are the paper's. Blind, A is the first ride: when
    it was the 80% ride the scale turns round (0 <-> 3, 1 <-> 2).

    Raises:
        ValueError: an option outside 0-4 or an unknown order.
    """
    if order not in ORDERS:
        raise ValueError(f"order {order!r}, expected one of {sorted(ORDERS)}")
    if not 0 <= option_shown < N_OPTIONS:
        raise ValueError(f"option {option_shown}, expected 0-{N_OPTIONS - 1}")
    first_is_high = ORDERS[order][0] == HIGH_SHARE
    if not blind or not first_is_high or option_shown in NEUTRAL:
        return option_shown
    return 3 - option_shown
