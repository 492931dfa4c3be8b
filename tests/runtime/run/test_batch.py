"""The batch engine as a library: which files a run takes, what it plans, how a failure reads."""

import os

from svbrdf_cli.run import batch
from svbrdf_cli.run import pipeline
from svbrdf_cli.errors import ImageReadError


def _touch(path, text="x"):
    path.write_text(text)
    return path


def test_collect_inputs_takes_photos_from_folders_and_named_files_as_given(tmp_path):
    d = tmp_path / "shoot"
    d.mkdir()
    for name in ("b.jpg", "a.PNG", "c.dng", "notes.txt", ".hidden.jpg"):
        _touch(d / name)
    (d / "sub.jpg").mkdir()  # a folder named like a photo is not a photo
    odd = _touch(tmp_path / "scan.weird")
    files, ignored = batch.collect_inputs([str(d), str(odd)])
    assert [os.path.basename(f) for f in files] == ["a.PNG", "b.jpg", "c.dng", "scan.weird"]
    assert ignored == 1  # notes.txt


def test_plan_skips_complete_sets_only_when_resuming_and_fails_duplicates(tmp_path):
    out = tmp_path / "out"
    done = out / "p0"
    done.mkdir(parents=True)
    _touch(done / pipeline.RECORD, "{}")
    (out / "p1").mkdir()  # an incomplete set (no record)
    files = ["in/p0.jpg", "in/p1.jpg", "in/p2.jpg", "other/p2.png"]
    errors = []
    job = batch.Job(output=str(out), skip_done=True)
    todo, skipped, failed = batch.plan_inputs(files, job, errors.append)
    assert todo == ["in/p2.jpg"] and skipped == 1 and failed == 2
    assert any("p1" in e and "--force" in e for e in errors) and any("rename one" in e for e in errors)

    errors.clear()
    job = batch.Job(output=str(out), skip_done=False)  # capture: an existing set is an error, complete or not
    todo, skipped, failed = batch.plan_inputs(files[:2], job, errors.append)
    assert todo == [] and skipped == 0 and failed == 2

    job.opts.force = True
    todo, skipped, failed = batch.plan_inputs(files[:2], job, errors.append)
    assert todo == files[:2] and skipped == failed == 0


def test_describe_failure_is_one_line():
    assert batch.describe_failure("a.jpg", ImageReadError("'a.jpg' is not an image.")) == "'a.jpg' is not an image."
    assert "smaller --size" in batch.describe_failure("a.jpg", MemoryError())
    line = batch.describe_failure("a.jpg", ValueError("bad\nsecond line"))
    assert "\n" not in line and "'a.jpg'" in line and "ValueError: bad" in line
