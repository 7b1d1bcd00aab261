"""read_json and read_yaml: the parsed object of a good file, one UserError line naming the file
otherwise; reason: a library's error in a few words."""

import numpy as np
import pytest

from sim2real.config import read_yaml
from sim2real.data.views import list_views
from sim2real.errors import UserError, reason
from sim2real.fileio import atomic_write_text, read_json, read_json_or_none
from sim2real.scene.scene import Scene


def _one_line(excinfo) -> str:
    msg = str(excinfo.value)
    assert "\n" not in msg, msg
    return msg


def test_good_file(tmp_path):
    f = tmp_path / "a.json"
    f.write_text('{"count": 3, "names": ["x", "y"], "nested": {"k": 0.5}}\n')
    assert read_json(f, "thing") == {"count": 3, "names": ["x", "y"], "nested": {"k": 0.5}}
    assert read_json_or_none(f) == {"count": 3, "names": ["x", "y"], "nested": {"k": 0.5}}


def test_missing_file(tmp_path):
    f = tmp_path / "nope.json"
    with pytest.raises(UserError) as e:
        read_json(f, "views manifest")
    assert _one_line(e) == f"cannot read views manifest {f}: No such file or directory"
    assert read_json_or_none(f) is None


def test_malformed_file(tmp_path):
    f = tmp_path / "bad.json"
    f.write_text('{"count": 3,\n "names": [}\n')
    with pytest.raises(UserError) as e:
        read_json(f, "scene description")
    # The decoder's own words, with the line and column of the fault (line 2, column 12: the "}").
    assert _one_line(e) == f"cannot read scene description {f}: not valid JSON (Expecting value: line 2 column 12 (char 24))"
    assert read_json_or_none(f) is None


@pytest.mark.parametrize("text,found", [("[1, 2]", "list"), ('"s"', "str"), ("7", "int")])
def test_not_an_object(tmp_path, text, found):
    f = tmp_path / "list.json"
    f.write_text(text)
    with pytest.raises(UserError) as e:
        read_json(f)
    assert _one_line(e) == f"cannot read JSON file {f}: expected a JSON object, found {found}"
    assert read_json_or_none(f) is None


def test_not_text_and_directory(tmp_path):
    f = tmp_path / "bin.json"
    f.write_bytes(b"\xff\xfe\x00{")
    with pytest.raises(UserError) as e:
        read_json(f, "x")
    assert _one_line(e) == f"cannot read x {f}: not a UTF-8 text file"
    d = tmp_path / "dir.json"
    d.mkdir()
    with pytest.raises(UserError) as e:
        read_json(d, "x")
    assert _one_line(e) == f"cannot read x {d}: Is a directory"


def test_call_sites_name_their_file(tmp_path):
    """A scene folder and a views folder with broken JSON: the error says which file and what."""
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "scene.json").write_text("{not json")
    with pytest.raises(UserError, match=r"^cannot read scene description .*scene\.json: not valid JSON"):
        Scene.load(scene)
    views = tmp_path / "views"
    views.mkdir()
    (views / "views.json").write_text("[]")
    with pytest.raises(UserError, match=r"^cannot read views manifest .*views\.json: expected a JSON object, found list$"):
        list_views(views)
    (views / "views.json").write_text('{"x": 1}')  # JSON, but not a views manifest
    with pytest.raises(UserError) as e:
        list_views(views)
    assert _one_line(e) == f"{views / 'views.json'} is not a views manifest of sim2real (format sim2real-views/1 with a count)"


def test_reason_keeps_the_words_and_drops_numbers_and_repeated_names():
    assert reason(FileNotFoundError(2, "No such file or directory", "/x/y.txt")) == "No such file or directory"
    assert reason(ValueError("first line\nsecond line")) == "first line"
    assert reason(ValueError()) == "ValueError"


def test_yaml_errors_say_where_in_one_line(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("data:\n  height: 64\n")
    assert read_yaml(f) == {"data": {"height": 64}}
    f.write_text("a: 1\n  b: 2\n")  # the colon of line 2 is its 4th character
    with pytest.raises(UserError) as e:
        read_yaml(f)
    assert _one_line(e) == f"cannot read config {f}: not valid YAML (line 2, column 4: mapping values are not allowed here)"
    with pytest.raises(UserError) as e:
        read_yaml(tmp_path / "none.yaml")
    assert _one_line(e) == f"cannot read config {tmp_path / 'none.yaml'}: No such file or directory"


def test_a_file_in_the_way_of_an_output_folder_is_one_line(tmp_path):
    (tmp_path / "a.png").write_text("x")
    for target in (tmp_path / "a.png" / "out.txt", tmp_path / "a.png" / "b" / "out.txt"):
        with pytest.raises(UserError) as e:
            atomic_write_text(target, "y")
        assert _one_line(e) == f"cannot write {target}: {tmp_path / 'a.png'} is a file, not a folder"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]  # nothing else written


def test_link_or_copy_links_replaces_and_copies_where_links_fail(tmp_path, monkeypatch):
    import os

    from sim2real.fileio import link_or_copy

    src, dst = tmp_path / "src.bin", tmp_path / "out" / "dst.bin"
    src.write_bytes(b"frame")
    link_or_copy(src, dst)
    assert os.stat(dst).st_ino == os.stat(src).st_ino  # the same file
    other = tmp_path / "other.bin"
    other.write_bytes(b"second")
    link_or_copy(other, dst)  # an existing name is replaced
    assert dst.read_bytes() == b"second"

    def no_link(a, b):
        raise OSError(18, "Invalid cross-device link")

    monkeypatch.setattr(os, "link", no_link)
    link_or_copy(src, dst)
    assert dst.read_bytes() == b"frame" and os.stat(dst).st_ino != os.stat(src).st_ino
    assert sorted(p.name for p in dst.parent.iterdir()) == ["dst.bin"]  # no temporary left


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077], ids=["022", "027", "077"])
def test_outputs_get_the_permissions_of_any_new_file_not_private_ones(tmp_path, umask):
    """Written atomically, a file and a folder get what a plain open() and mkdir() give under the
    process's umask (0644 and 0755 under 022), not tempfile's private 0600 and 0700."""
    import os
    import stat

    from sim2real.fileio import atomic_save_npz, link_or_copy, temp_dir_beside

    old = os.umask(umask)
    try:
        (tmp_path / "plain.txt").write_text("x")
        (tmp_path / "plain").mkdir()
        atomic_write_text(tmp_path / "out" / "a.txt", "y")
        atomic_save_npz(tmp_path / "out" / "b.npz", {"x": np.zeros(2)})
        link_or_copy(tmp_path / "plain.txt", tmp_path / "out" / "c.txt")
        folder = temp_dir_beside(tmp_path / "out" / "result", "partial-")
    finally:
        os.umask(old)

    def mode(p):
        return stat.S_IMODE(os.stat(p).st_mode)

    assert mode(tmp_path / "plain.txt") == 0o666 & ~umask and mode(tmp_path / "plain") == 0o777 & ~umask
    for name in ("a.txt", "b.npz", "c.txt"):
        assert mode(tmp_path / "out" / name) == mode(tmp_path / "plain.txt"), name
    assert mode(folder) == mode(tmp_path / "plain")
    assert folder.parent == tmp_path / "out" and folder.name.startswith(".result.partial-") and not any(folder.iterdir())
    assert sorted(p.name for p in (tmp_path / "out").iterdir() if p != folder) == ["a.txt", "b.npz", "c.txt"]


def test_a_staged_output_folder_appears_whole_or_not_at_all(tmp_path):
    """What the block writes appears under the name at its end; a block that raises leaves the
    name as it found it (absent, or the empty folder the user made) and nothing hidden beside it."""
    from sim2real.fileio import staged_output_dir

    def names(folder):
        return sorted(p.name for p in folder.iterdir())

    out = tmp_path / "new" / "out"
    with staged_output_dir(out) as staged:
        assert not out.exists() and staged.parent == out.parent  # beside it, renamed at the end
        (staged / "sub").mkdir()
        (staged / "sub" / "a.txt").write_text("a")
    assert (out / "sub" / "a.txt").read_text() == "a" and names(out.parent) == ["out"]

    for existed in (False, True):
        out = tmp_path / f"failed{existed}"
        if existed:
            out.mkdir()
        with pytest.raises(KeyboardInterrupt):
            with staged_output_dir(out) as staged:
                (staged / "half.txt").write_text("h")
                raise KeyboardInterrupt
        assert out.exists() == existed and (not existed or names(out) == [])
        assert not [p for p in tmp_path.iterdir() if p.name.startswith(f".failed{existed}")]

    empty = tmp_path / "empty"
    empty.mkdir()
    with staged_output_dir(empty) as staged:  # an empty folder is taken
        (staged / "b.txt").write_text("b")
    assert names(empty) == ["b.txt"]

    body = []
    with pytest.raises(UserError) as e:
        with staged_output_dir(empty):
            body.append(1)
    assert _one_line(e).startswith(f"output directory {empty} already holds other data (b.txt, ...)") and not body

    disk = tmp_path / "big_disk"
    (disk / "videos").mkdir(parents=True)
    (tmp_path / "link").symlink_to(disk / "videos")  # an empty folder elsewhere, linked
    (tmp_path / "dangling").symlink_to(disk / "later")  # a folder still to be made there
    for link in ("link", "dangling"):
        with staged_output_dir(tmp_path / link) as staged:
            assert staged.parent == disk  # written where the link points
            (staged / "c.txt").write_text(link)
        assert (tmp_path / link).is_symlink() and (tmp_path / link / "c.txt").read_text() == link
    assert names(disk) == ["later", "videos"]

    raced = tmp_path / "raced"
    with pytest.raises(UserError) as e:
        with staged_output_dir(raced) as staged:
            (staged / "mine.txt").write_text("m")
            raced.mkdir()
            (raced / "theirs.txt").write_text("t")  # another program wrote there meanwhile
    assert _one_line(e) == (f"output directory {raced} was filled by something else while this command ran; "
                            f"choose an empty one")
    assert names(raced) == ["theirs.txt"] and not list(tmp_path.glob(".raced*"))


def test_an_output_filled_in_place_is_removed_when_its_command_fails(tmp_path):
    """removed_on_failure: kept when the block ends; when it raises, a folder it made is removed
    and a user's empty folder is emptied (files, folders, links) but kept."""
    from sim2real.fileio import removed_on_failure

    ok = tmp_path / "ok"
    with removed_on_failure(ok) as out:
        (out / "a.txt").write_text("a")
    assert (ok / "a.txt").read_text() == "a"

    outside = tmp_path / "outside.txt"
    outside.write_text("not the command's")
    made = tmp_path / "made"
    made.mkdir()
    for out in (tmp_path / "new" / "demo", made):
        with pytest.raises(RuntimeError, match="failed"):
            with removed_on_failure(out) as d:
                (d / "run").mkdir()
                (d / "run" / "last.pt").write_bytes(b"x")
                (d / "link").symlink_to(outside)
                raise RuntimeError("failed")
    assert not (tmp_path / "new" / "demo").exists() and list(made.iterdir()) == []
    assert outside.read_text() == "not the command's"  # a link is removed, not what it points to
    with pytest.raises(UserError, match="already holds other data"):
        with removed_on_failure(ok):
            pass
    assert (ok / "a.txt").read_text() == "a"


def test_free_space_is_checked_where_the_output_will_go(tmp_path, monkeypatch):
    """check_free_space asks the nearest existing folder of the path and refuses, in one line with
    both sizes, a need beyond its free bytes (MiB below 1 GiB, GiB above)."""
    import collections
    import shutil

    from sim2real.fileio import check_free_space

    usage = collections.namedtuple("usage", "total used free")
    asked = []
    monkeypatch.setattr(shutil, "disk_usage", lambda p: asked.append(p) or usage(0, 0, 100 * 2**20))
    check_free_space(tmp_path / "new" / "out", 100 * 2**20, "a video", "write elsewhere")  # exactly enough
    assert asked == [tmp_path]  # the folder that exists, not the one still to be made
    with pytest.raises(UserError) as e:
        check_free_space(tmp_path / "out", 100 * 2**20 + 1, "a video", "write elsewhere")
    assert _one_line(e) == f"a video needs at least 100.0 MiB but {tmp_path} has 100.0 MiB free; write elsewhere"
    with pytest.raises(UserError) as e:
        check_free_space(tmp_path, 3 * 2**30, "a pool", "lower it")
    assert _one_line(e) == f"a pool needs at least 3.00 GiB but {tmp_path} has 100.0 MiB free; lower it"
