"""The capture job's own pieces: output size and naming."""

from svbrdf_cli.run import pipeline


def test_output_size_defaults_to_a_power_of_two_within_the_crop_capped():
    assert pipeline.output_size(pipeline.Options(), 3000) == pipeline.DEFAULT_SIZE
    assert pipeline.output_size(pipeline.Options(), 300) == 256
    assert pipeline.output_size(pipeline.Options(), 768) == 512
    assert pipeline.output_size(pipeline.Options(), 781) == 512
    assert pipeline.output_size(pipeline.Options(), 1023) == 512
    assert pipeline.output_size(pipeline.Options(), 1024) == 1024
    assert pipeline.output_size(pipeline.Options(), 100) == pipeline.MIN_SIZE
    assert pipeline.output_size(pipeline.Options(size=2048), 300) == 2048


def test_output_folder_is_the_photo_stem(tmp_path):
    assert pipeline.output_folder(tmp_path, "/a/b/IMG_0042.DNG") == str(tmp_path / "IMG_0042")
