"""Each user's editor files in the agent context: limits, newest kept, nobody reads another's."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from common.messages import (
    FileContent,
    FileList,
    FileListRequest,
    MessageError,
    OkReply,
    ReadFile,
    SaveFile,
    decode,
    encode,
)
from common.service import RequestError
from services.context.user_files import FileStoreError, UserFiles

SOURCE = b"from common.controller import Controller\n"


@pytest.fixture(params=["disk", "memory"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> UserFiles:
    root = tmp_path / "arena.files" if request.param == "disk" else None
    return UserFiles(root, max_files=3, max_bytes=1000)


def test_a_saved_file_reads_back_for_its_owner(store: UserFiles) -> None:
    store.save("alice", "mine.py", SOURCE)
    assert store.read("alice", "mine.py")[0] == SOURCE
    assert [f.name for f in store.listing("alice")] == ["mine.py"]


def test_another_user_cannot_read_or_list_it(store: UserFiles) -> None:
    store.save("alice", "mine.py", SOURCE)
    with pytest.raises(FileStoreError, match=r"you have no file named mine\.py") as caught:
        store.read("bob", "mine.py")
    assert caught.value.code == "not_found"
    assert store.listing("bob") == []


def test_the_oldest_go_when_a_user_has_too_many(store: UserFiles) -> None:
    for i in range(5):
        store.save("alice", f"f{i}.py", SOURCE)
    assert [f.name for f in store.listing("alice")] == ["f4.py", "f3.py", "f2.py"]
    store.save("alice", "f2.py", b"# again\n")  # saving again makes it the newest
    assert store.listing("alice")[0].name == "f2.py"
    with pytest.raises(FileStoreError):
        store.read("alice", "f0.py")


def test_a_file_too_big_is_refused_with_the_reason(store: UserFiles) -> None:
    with pytest.raises(FileStoreError, match=r"big.py is 1001 bytes; files are kept up to 0 KiB"):
        store.save("alice", "big.py", b"#" * 1001)
    assert store.listing("alice") == []


@pytest.mark.parametrize("name", ["../bob/x.py", "x.txt", ".hidden.py", "a/b.py", ""])
def test_a_name_that_is_not_a_plain_py_file_is_refused(store: UserFiles, name: str) -> None:
    with pytest.raises(FileStoreError, match="is not a file name"):
        store.save("alice", name, SOURCE)
    with pytest.raises(FileStoreError, match="is not a file name"):
        store.read("alice", name)


def test_files_on_disk_survive_a_restart_and_are_private(tmp_path: Path) -> None:
    root = tmp_path / "arena.files"
    UserFiles(root).save("alice", "keep.py", SOURCE)
    again = UserFiles(root)
    assert again.read("alice", "keep.py")[0] == SOURCE
    assert (root / "alice" / "keep.py").stat().st_mode & 0o077 == 0
    assert not list((root / "alice").glob(".*"))  # no temporary file left behind


def test_the_wire_types_name_no_user_and_refuse_a_path() -> None:
    # The context files requests under the envelope's user: no field can name another.
    for cls in (SaveFile, ReadFile, FileListRequest):
        assert "user" not in {f.name for f in msgspec.structs.fields(cls)}
    raw = encode(ReadFile(name="ok.py")).replace(b"ok.py", b"../..")
    with pytest.raises(MessageError):
        decode(raw, ReadFile)


def test_requests_answer_for_the_sender_only(store: UserFiles) -> None:
    """The context answers file requests for the envelope's user: a name in a request never
    reaches another user's folder, and a refusal is a request error, not a crash."""
    reply = store.answer("alice", SaveFile(name="mine.py", source=SOURCE))
    assert isinstance(reply, OkReply) and "mine.py" in reply.detail
    content = store.answer("alice", ReadFile(name="mine.py"))
    assert isinstance(content, FileContent) and content.source == SOURCE
    with pytest.raises(RequestError) as caught:
        store.answer("bob", ReadFile(name="mine.py"))
    assert caught.value.code == "not_found"
    listing = store.answer("bob", FileListRequest())
    assert isinstance(listing, FileList) and listing.files == []
    with pytest.raises(RequestError) as too_big:
        store.answer("alice", SaveFile(name="big.py", source=b"#" * 2000))
    assert too_big.value.code == "bad_request"
