"""Wire types of LTI 1.3: a platform's user made a lab account, a grade passed back.

The lti service (services/lti/) verifies a launch from an LMS, then asks the
registry for the account of the platform's user with a sealed
:class:`LtiAccountRequest` on ``registry/lti`` (only a session of an account
with the ``lti`` role may ask); the registry makes or matches the account, puts
it in the course and answers an :class:`LtiAccount` with a resume token the
page logs in with. The grader publishes a :class:`Graded` (sealed with its
service session) on ``grader/<g>/graded`` as each submission is graded, naming
neither the student nor the score (anyone may read a put); the lti service asks
the grader for them and posts a launched student's score to the platform.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.base import Ident, Message, ShortText

PlatformText = Annotated[str, msgspec.Meta(min_length=1, max_length=255)]
"""An issuer URL or a platform's user id (LTI's ``sub`` is at most 255 characters)."""


class LtiAccountRequest(Message, frozen=True):
    """The account of platform user (issuer, subject), made on first launch, in ``course``."""

    issuer: PlatformText
    subject: PlatformText
    course: Ident
    role: Literal["student", "teacher"]
    name: ShortText = ""  # the platform's display name (the roster's name column)
    email: ShortText = ""


class LtiAccount(Message, frozen=True):
    """The lab account a launch logs in as, and a resume token for the page (used once)."""

    user: Ident
    created: bool  # made by this launch
    joined: bool  # put in the course (or given another role there) by this launch
    resume: Annotated[bytes, msgspec.Meta(max_length=1024)]  # an encoded SignedResume


class Graded(Message, frozen=True):
    """A submission graded (published by the grader once, as it is written): no student,
    no score; the lti service asks the grader for them (SubmissionsQuery, its lti role)."""

    submission: Ident
    assignment: Ident
    course: Ident
    graded_at: float  # wall-clock seconds


__all__ = ["Graded", "LtiAccount", "LtiAccountRequest", "PlatformText"]
