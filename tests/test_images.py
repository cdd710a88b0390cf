"""Image round trips through OpenImageIO: exact values, channel names, colour-space metadata."""

from __future__ import annotations

import numpy as np
import pytest

from usdahd import images
from usdahd.errors import ImageError, UsageError

pytest.importorskip("OpenImageIO")

RNG = np.random.default_rng(11)


def random_pixels(fmt, shape):
    if fmt == "half":
        return (RNG.standard_normal(shape) * 100).astype(np.float16)
    if fmt == "float":
        return (RNG.standard_normal(shape) * 1e3).astype(np.float32)
    if fmt == "unorm8":
        return RNG.integers(0, 256, shape, dtype=np.uint8)
    return RNG.integers(-128, 128, shape, dtype=np.int8)


@pytest.mark.parametrize(
    ("fmt", "ext", "channels", "color_space"),
    [
        ("half", ".exr", ("R", "G", "B"), "lin_rec709_scene"),
        ("half", ".exr", tuple(f"c{k}.{c}" for k in range(9) for c in "RGB"), "raw"),
        ("float", ".exr", ("R", "G", "B"), "lin_rec709_scene"),
        ("unorm8", ".png", ("R", "G", "B"), "raw"),
        ("unorm8", ".png", ("R", "G", "B", "A"), "raw"),  # no premultiplication
        ("unorm8", ".png", ("X", "Y"), "raw"),
        ("unorm8", ".png", ("R", "G", "B"), "srgb_rec709_scene"),
        ("unorm8", ".tif", ("Y",), "raw"),
        ("snorm8", ".tif", ("X", "Y"), "raw"),
        ("snorm8", ".tif", ("R", "G", "B"), "raw"),
    ],
)
def test_round_trip_exact(tmp_path, fmt, ext, channels, color_space):
    px = random_pixels(fmt, (7, 5, len(channels)))
    if fmt == "snorm8":
        px[0, 0, 0], px[0, 1, 0] = -128, 127  # extremes survive
    path = tmp_path / f"img{ext}"
    images.write(path, px, color_space=color_space, channels=channels, attributes={"izScale": 2.5})
    img = images.read(path)
    assert img.format == fmt
    assert img.pixels.dtype == px.dtype and img.pixels.shape == px.shape
    assert np.array_equal(img.pixels, px)
    assert img.channels == channels
    assert img.color_space == color_space
    if ext != ".png":
        assert img.attributes.get("izScale") == pytest.approx(2.5)
    # no temp files left behind
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_exr_compression_and_channel_selection(tmp_path):
    px = random_pixels("half", (4, 6, 3))
    path = tmp_path / "a.exr"
    images.write(path, px, color_space="lin_rec709_scene", compression="piz")
    img = images.read(path, channels=("B", "R"))
    assert img.attributes["compression"] == "piz"
    assert np.array_equal(img.pixels, px[..., [2, 0]])
    assert np.array_equal(img.channel("R"), px[..., 0])
    with pytest.raises(ImageError, match="missing channels"):
        images.read(path, channels=("Z",))


def test_float32_cast_to_half_and_2d(tmp_path):
    px = RNG.standard_normal((3, 4)).astype(np.float32)
    path = tmp_path / "g.exr"
    images.write(path, px, color_space="raw", format="half")
    img = images.read(path)
    assert img.pixels.shape == (3, 4, 1) and img.format == "half"
    assert np.array_equal(img.pixels[..., 0], px.astype(np.float16))


def test_atomic_write_keeps_previous_file_on_failure(tmp_path):
    path = tmp_path / "keep.exr"
    good = random_pixels("half", (2, 2, 3))
    images.write(path, good, color_space="raw")
    before = path.read_bytes()
    bad = good.astype(np.float32)
    bad[0, 0, 0] = np.nan
    with pytest.raises(ImageError, match="NaN"):
        images.write(path, bad, color_space="raw")
    assert path.read_bytes() == before


def test_bad_inputs_raise_clear_errors(tmp_path):
    with pytest.raises(ImageError, match="no such image file"):
        images.read(tmp_path / "missing.exr")
    (tmp_path / "junk.exr").write_bytes(b"not an image")
    with pytest.raises(ImageError, match="cannot read image"):
        images.read(tmp_path / "junk.exr")
    with pytest.raises(ImageError, match="cannot hold snorm8"):
        images.write(tmp_path / "d.png", random_pixels("snorm8", (2, 2, 2)), color_space="raw")
    with pytest.raises(ImageError, match="quantize first"):
        images.write(
            tmp_path / "d.tif", np.zeros((2, 2, 2), np.float32), color_space="raw", format="snorm8"
        )
    with pytest.raises(ImageError, match="unsupported extension"):
        images.write(tmp_path / "d.jpg", random_pixels("unorm8", (2, 2, 3)), color_space="raw")
    with pytest.raises(ImageError, match="cannot store int32"):
        images.write(tmp_path / "d.exr", np.zeros((2, 2, 3), np.int32), color_space="raw")
    with pytest.raises(ImageError, match="3 channels but 2"):
        images.write(
            tmp_path / "d.exr", random_pixels("half", (2, 2, 3)), color_space="raw", channels="RG"
        )
    with pytest.raises(UsageError, match="unknown image format"):
        images.write(
            tmp_path / "d.exr", random_pixels("half", (2, 2, 3)), color_space="raw", format="f8"
        )


def test_exr_many_channels_read_back_by_name_in_written_order(tmp_path):
    # OpenEXR stores channels sorted by name; reading by name must undo that.
    names = tuple(f"{c}{k}" for c in "RGB" for k in range(9)) + ("A",)
    px = np.arange(2 * 3 * len(names), dtype=np.float32).reshape(2, 3, len(names))
    path = tmp_path / "side.exr"
    images.write(path, px, format="float", color_space="raw", channels=names)
    back = images.read(path, channels=names)
    np.testing.assert_array_equal(back.pixels, px)
    whole = images.read(path)
    for i, n in enumerate(names):
        np.testing.assert_array_equal(whole.channel(n), px[..., i])


def test_data_png_is_tagged_linear_and_rgba_round_trips_bit_exactly(tmp_path):
    """Lightmap PNGs: RGB/RGBA uint8 data, gAMA 1.0 (not sRGB) in the file, alpha never
    premultiplied on write or read."""
    import OpenImageIO as oiio

    rng = np.random.default_rng(7)
    px = rng.integers(0, 256, (5, 7, 4)).astype(np.uint8)
    px[0, 0] = (200, 100, 50, 0)  # alpha 0 must keep its colour
    f = tmp_path / "d.png"
    images.write(f, px, color_space="raw")
    assert b"gAMA" in f.read_bytes() and b"sRGB" not in f.read_bytes()[:64]
    back = images.read(f)
    assert back.channels == ("R", "G", "B", "A") and back.color_space == "raw"
    np.testing.assert_array_equal(back.pixels, px)
    inp = oiio.ImageInput.open(str(f))  # the file's own claim, as other tools read it
    assert inp.spec().get_string_attribute("oiio:ColorSpace") == "lin_rec709_scene"
    inp.close()
    images.write(tmp_path / "s.png", px[..., :3], color_space="srgb_rec709_scene")
    assert b"sRGB" in (tmp_path / "s.png").read_bytes()  # colour PNGs keep their sRGB chunk


@pytest.mark.parametrize("ext", [".exr", ".png", ".tif"])
def test_same_pixels_give_the_same_bytes(tmp_path, monkeypatch, ext):
    """Bakes are byte-reproducible: no write time is stamped (lightmap names are content hashes)."""
    import time

    import OpenImageIO as oiio

    px = (
        RNG.integers(0, 256, (8, 8, 3), dtype=np.uint8)
        if ext != ".exr"
        else random_pixels("half", (8, 8, 3))
    )
    a, b = tmp_path / f"a{ext}", tmp_path / f"b{ext}"
    images.write(a, px, color_space="raw", channels=("R", "G", "B"))
    time.sleep(1.1)  # DateTime has a resolution of one second
    images.write(b, px, color_space="raw", channels=("R", "G", "B"))
    assert a.read_bytes() == b.read_bytes()
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    images.write(a, px, color_space="raw", channels=("R", "G", "B"))
    if ext == ".exr":
        assert oiio.ImageInput.open(str(a)).spec().getattribute("DateTime") == "2023:11:14 22:13:20"


def test_read_texels_keeps_straight_colour_under_alpha(tmp_path):
    """A PNG stores straight (unassociated) colour: read_texels returns it as stored, not
    multiplied by alpha (OpenImageIO's default would give 0.8 x alpha: a cut-out's albedo dark
    at its edges and 0 where it is transparent)."""
    oiio = pytest.importorskip("OpenImageIO")
    img = np.zeros((2, 2, 4), np.float32)
    img[..., :3] = 0.8
    img[..., 3] = [[0.5, 0.0], [1.0, 0.25]]
    spec = oiio.ImageSpec(2, 2, 4, oiio.UINT8)
    spec.attribute("oiio:UnassociatedAlpha", 1)
    path = tmp_path / "cut.png"
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(img)
    out.close()
    data, fmt = images.read_texels(path)
    assert fmt == "uint8"
    np.testing.assert_allclose(data[..., :3], 0.8, atol=1 / 255)
    np.testing.assert_allclose(data[..., 3], img[..., 3], atol=1 / 255)


@pytest.mark.parametrize(("fmt", "ext"), [("half", ".exr"), ("float", ".exr"), ("unorm8", ".png")])
def test_read_native_in_strips_equals_a_whole_read(tmp_path, monkeypatch, fmt, ext):
    """Big scanline images are read in strips (less peak memory): the same pixels as one
    read, also when the height is not a multiple of the strip."""
    px = random_pixels(fmt, (150, 70, 3))
    path = str(tmp_path / f"img{ext}")
    images.write(path, px, format=fmt, channels=("R", "G", "B"), color_space="raw")
    whole = images.read_native(path)
    monkeypatch.setattr(images, "STRIP_BYTES", 1024)
    monkeypatch.setattr(images, "STRIP_ROWS", 16)
    strips = images.read_native(path)
    assert strips[1:] == whole[1:]
    assert strips[0].dtype == whole[0].dtype
    np.testing.assert_array_equal(strips[0], whole[0])
    np.testing.assert_array_equal(whole[0], px)
