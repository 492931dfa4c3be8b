"""The capture job's own pieces: output size and naming."""

from svbrdf_cli.run import pipeline


def test_output_size_defaults_to_the_crop_capped():
    assert pipeline.output_size(pipeline.Options(), 3000) == pipeline.DEFAULT_SIZE
    assert pipeline.output_size(pipeline.Options(), 300) == 300
    assert pipeline.output_size(pipeline.Options(), 100) == pipeline.MIN_SIZE
    assert pipeline.output_size(pipeline.Options(size=2048), 300) == 2048


def test_output_folder_is_the_photo_stem(tmp_path):
    assert pipeline.output_folder(tmp_path, "/a/b/IMG_0042.DNG") == str(tmp_path / "IMG_0042")
