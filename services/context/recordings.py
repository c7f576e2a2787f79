"""An agent context's answers about recordings: list them, download one in chunks.

Rights: a user lists and downloads the runs of their own requests; the
context's managers (its owner, or ``kick`` there) those of anyone. Another
user's recording is ``forbidden`` (not hidden: request ids are not secrets,
the contents are).
"""

from __future__ import annotations

from pathlib import Path

from common.auth import Principal
from common.messages import (
    MAX_CHUNK,
    Message,
    RecordingChunk,
    RecordingGet,
    RecordingList,
    RecordingListRequest,
)
from common.messages.recording import MAX_LISTED
from common.recording.store import RecordingStore
from common.service import RequestError


class RecordingRequests:
    def __init__(self, store: RecordingStore | None, ctx: str) -> None:
        self.store = store
        self.ctx = ctx

    def answer(
        self, principal: Principal, request: RecordingListRequest | RecordingGet, manages: bool
    ) -> Message:
        if self.store is None:
            raise RequestError(
                "not_found", f"{self.ctx} keeps no recordings (started without a data directory)"
            )
        if isinstance(request, RecordingListRequest):
            return self._list(principal, request, manages)
        return self._get(principal, request, manages)

    def _list(self, principal: Principal, request: RecordingListRequest, manages: bool) -> Message:
        assert self.store is not None
        others = request.all_users or request.user not in (None, principal.user)
        if others and not manages:
            raise RequestError(
                "forbidden",
                f"only the owner of {self.ctx} or a user with 'kick' there may list "
                "other users' recordings",
            )
        users = self.store.users() if request.all_users else [request.user or principal.user]
        found = sorted(self.store.listing(users), key=lambda r: r.start)
        return RecordingList(ctx=self.ctx, keep=self.store.keep, recordings=found[-MAX_LISTED:])

    def _get(self, principal: Principal, request: RecordingGet, manages: bool) -> Message:
        assert self.store is not None
        found = self.store.find(request.name)
        if found is None:
            raise RequestError("not_found", f"no recording {request.name} in {self.ctx}")
        owner, path = found
        if owner != principal.user and not manages:
            raise RequestError("forbidden", f"recording {request.name} is not yours")
        if request.summary:
            path = self.store.summary_path(path)
        try:
            with path.open("rb") as f:
                total = f.seek(0, 2)
                if request.offset > total:
                    raise RequestError("bad_request", f"offset {request.offset} is past the end")
                f.seek(request.offset)
                data = f.read(MAX_CHUNK)
        except FileNotFoundError:
            what = "summary" if request.summary else "recording"
            raise RequestError("not_found", f"the {what} of {request.name} is gone") from None
        except OSError as exc:
            raise RequestError("internal", f"cannot read {request.name}: {exc.strerror}") from None
        return RecordingChunk(name=request.name, offset=request.offset, total=total, data=data)


def recordings_dir(ctx: str, data_dir: Path | None, explicit: Path | None) -> Path | None:
    """Where a context keeps its recordings: explicit, else ``<data dir>/recordings/<ctx>``
    (a data dir may be shared by several contexts)."""
    if explicit is not None:
        return explicit
    return None if data_dir is None else data_dir / "recordings" / ctx
