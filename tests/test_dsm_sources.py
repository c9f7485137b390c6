"""Remote DSM access only when asked for (a DSM path must not reach the network unasked): URLs, network file systems,
VRTs that point at them (at any depth) and local files that GDAL would follow to a
server are refused, and nothing reaches the server; allowed, the same DSM opens."""

from __future__ import annotations

import json

import pytest

from cevm.errors import InputError
from cevm.ingest.dsm import DsmSampler
from cevm.ingest.dsm_sources import check_local, is_remote
from test_parallel import cog_dir, http_root, logs, run  # noqa: F401 (fixtures)


def _requests(log) -> list:
    return [json.loads(line) for line in log.read_text().splitlines()]


def _vrt(path, source: str, relative: bool = False, srs: str = "EPSG:27700", band_attrs: str = "",
         band_head: str = "") -> None:
    path.write_text(f"""<VRTDataset rasterXSize="500" rasterYSize="500"><SRS>{srs}</SRS>
  <GeoTransform>484900, 2, 0, 239900, 0, -2</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1"{band_attrs}>{band_head}<SimpleSource>
    <SourceFilename relativeToVRT="{int(relative)}">{source}</SourceFilename><SourceBand>1</SourceBand>
  </SimpleSource></VRTRasterBand></VRTDataset>""")


@pytest.mark.parametrize("name", ["https://example.org/dsm.tif", "/vsicurl/https://example.org/dsm.vrt",
                                  "/vsis3/bucket/dsm.tif", "/vsigs/b/x.tif", "/vsiaz/c/x.tif",
                                  "/vsizip//vsicurl/http://h/x.zip/a.tif", "vrt://https://h/x.tif?bands=1",
                                  "WMS:http://h/wms", "/vsiunknownfs/x.tif"])
def test_network_names_are_remote(name):
    assert is_remote(name)


@pytest.mark.parametrize("name", ["/data/dsm.tif", "dsm/a.tif", "/vsizip/local.zip/a.tif", "/vsimem/x.tif",
                                  "vrt:///data/a.tif?bands=1", "C:/dsm/a.tif"])
def test_local_names_are_not_remote(name):
    assert not is_remote(name)


def test_remote_dsm_is_refused_without_permission_and_nothing_is_fetched(cog_dir, http_root, logs, tmp_path,
                                                                         monkeypatch):
    monkeypatch.delenv("CEVM_ALLOW_REMOTE_DSM", raising=False)
    base, log = http_root
    before = len(_requests(log))
    # a local VRT of the remote tiles, and a local VRT of that VRT
    _vrt(tmp_path / "remote.vrt", f"{base}/tile_0_0.tif")
    _vrt(tmp_path / "outer.vrt", "remote.vrt", relative=True)
    # a local ".tif" that is a WMS description pointing at the server
    (tmp_path / "wms.tif").write_text(
        f"<GDAL_WMS><Service name=\"TMS\"><ServerUrl>{base}/${{z}}/${{x}}/${{y}}.png</ServerUrl></Service>"
        "<DataWindow><UpperLeftX>-20037508.34</UpperLeftX><UpperLeftY>20037508.34</UpperLeftY>"
        "<LowerRightX>20037508.34</LowerRightX><LowerRightY>-20037508.34</LowerRightY><TileLevel>1</TileLevel>"
        "<TileCountX>1</TileCountX><TileCountY>1</TileCountY><YOrigin>top</YOrigin></DataWindow>"
        "<Projection>EPSG:3857</Projection><BlockSizeX>256</BlockSizeX><BlockSizeY>256</BlockSizeY>"
        "<BandsCount>1</BandsCount></GDAL_WMS>")
    (tmp_path / "dir").mkdir()
    (tmp_path / "dir" / "a.tif").write_bytes((cog_dir / "tile_0_0.tif").read_bytes())
    (tmp_path / "dir" / "b.tif").write_bytes((tmp_path / "wms.tif").read_bytes())
    for dsm, says in [(f"{base}/dsm.vrt", "is a network location"),
                      (f"/vsicurl/{base}/dsm.vrt", "is a network location"),
                      (tmp_path / "remote.vrt", f"refers to '{base}/tile_0_0.tif'"),
                      (tmp_path / "outer.vrt", f"refers to '{base}/tile_0_0.tif'"),
                      (tmp_path / "wms.tif", "neither a GeoTIFF nor a VRT"),
                      (tmp_path / "dir", "neither a GeoTIFF nor a VRT")]:
        with pytest.raises(InputError) as info:
            DsmSampler.open(dsm)
        assert says in str(info.value) and ("--allow-remote-dsm" in str(info.value)), str(info.value)
    assert len(_requests(log)) == before  # not one request reached the server
    # the CLI: one line, exit code 2 (bad input), nothing fetched
    res = run("ingest", logs, "--store", tmp_path / "s.sqlite", "--dsm", tmp_path / "outer.vrt", "-q")
    assert res.exit_code == 2 and "remote DSM access is off" in res.output
    assert len(_requests(log)) == before


def test_remote_dsm_opens_when_allowed(cog_dir, http_root, tmp_path, monkeypatch):
    base, log = http_root
    _vrt(tmp_path / "remote.vrt", f"{base}/tile_0_0.tif")
    before = len(_requests(log))
    monkeypatch.setenv("CEVM_ALLOW_REMOTE_DSM", "1")
    with DsmSampler.open(tmp_path / "remote.vrt") as s:
        assert len(s.tiles) == 1
    monkeypatch.delenv("CEVM_ALLOW_REMOTE_DSM")
    with DsmSampler.open(f"{base}/dsm.vrt", allow_remote=True) as s:
        assert s.tiles[0].width == 1000
    assert len(_requests(log)) > before


def test_local_vrts_open_and_harmless_texts_are_not_refused(cog_dir, tmp_path, monkeypatch):
    monkeypatch.delenv("CEVM_ALLOW_REMOTE_DSM", raising=False)
    assert check_local(str(cog_dir / "dsm.vrt")) == "VRT"
    assert check_local(str(cog_dir / "tile_0_0.tif")) == "GTiff"
    # an SRS that holds a URI is no source
    wkt = 'PROJCS["x",GEOGCS["y",DATUM["z",SPHEROID["a",6378137,298.257]],PRIMEM["G",0],UNIT["d",0.0174]],' \
          'PROJECTION["Transverse_Mercator"],UNIT["m",1],AUTHORITY["http://example.org/crs","1"]]'
    _vrt(tmp_path / "ok.vrt", str(cog_dir / "tile_0_0.tif"), srs=wkt)
    assert check_local(str(tmp_path / "ok.vrt")) == "VRT"
    with DsmSampler.open(cog_dir / "dsm.vrt") as s:
        assert len(s.tiles) == 1 and s.tiles[0].driver == "VRT"


def test_vrt_with_python_code_or_a_loop_is_refused(cog_dir, tmp_path):
    _vrt(tmp_path / "py.vrt", str(cog_dir / "tile_0_0.tif"), band_attrs=' subClass="VRTDerivedRasterBand"',
         band_head="<PixelFunctionType>f</PixelFunctionType><PixelFunctionLanguage>Python</PixelFunctionLanguage>")
    with pytest.raises(InputError, match="Python pixel function"):
        check_local(str(tmp_path / "py.vrt"))
    _vrt(tmp_path / "loop.vrt", "loop.vrt", relative=True)
    with pytest.raises(InputError, match="refers to itself"):
        check_local(str(tmp_path / "loop.vrt"))


@pytest.mark.parametrize("layout", [dict(tiled=False, blockysize=40_000), dict(tiled=True, blockxsize=16_384,
                                                                              blockysize=16_384)],
                         ids=["one 40000-px strip", "16384-px tiles"])
def test_a_raster_of_huge_blocks_is_refused_before_any_pixel_is_read(tmp_path, layout):
    """A 40,000 x 40,000 GeoTIFF of one deflate strip (kilobytes on disk, 6.4 GB
    decoded) drove ingest to 6.3 GB, 16,384-pixel tiles to 1.24 GB. Its header says so:
    refused when the DSM is opened, with the block size and the way out, and `cevm
    ingest` stops with exit 2 before any file is read."""
    import rasterio
    from rasterio.transform import from_origin
    from typer.testing import CliRunner

    from cevm.cli import app
    from cevm.errors import InputError

    big = tmp_path / "big.tif"
    with rasterio.open(big, "w", driver="GTiff", width=40_000, height=40_000, count=1, dtype="float32",
                       crs="EPSG:27700", transform=from_origin(480_000, 240_000, 2.0, 2.0), compress="deflate",
                       sparse_ok=True, **layout):
        pass  # nothing written: every block sparse
    assert big.stat().st_size < 200_000
    with pytest.raises(InputError, match=r"take [\d,]+ MB each decoded, over the 64 MB") as ei:
        DsmSampler.open(big)
    assert "big.tif" in str(ei.value) and "TILED=YES" in str(ei.value)
    from test_ingest import write_srf

    (tmp_path / "logs").mkdir()
    write_srf(tmp_path / "logs" / "a.csv", "EB-01", 1_557_820_800, 0, n=120)
    res = CliRunner().invoke(app, ["ingest", str(tmp_path / "logs"), "--dsm", str(big), "--store",
                                   str(tmp_path / "s.sqlite")])
    assert res.exit_code == 2 and "MB each decoded" in res.output, res.output
    assert not (tmp_path / "s.sqlite").exists()
