

def test_offsets_are_checked(tmp_path):
    src = tmp_path / "videos"
    src.mkdir()
    frames = [np.full((16, 16), 10 * i, np.uint8) for i in range(4)]
    R.write_video(src / "a.mkv", frames)
    res = _ingest(src, "--out", tmp_path / "ds", "--camera", "a=a.mkv", "--offset", "a=-1")
    assert res.exit_code == 2 and "before 0" in res.output and "--offset" in res.output
    res = _ingest(src, "--out", tmp_path / "ds", "--camera", "a=a.mkv", "--offset", "b=0.5")
    assert res.exit_code == 2 and "--offset b: not a camera given with --camera" in res.output
    res = _ingest(src, "--out", tmp_path / "ds", "--camera", "a=a.mkv", "--offset", "a=soon")
    assert res.exit_code == 2 and "expected a number of seconds" in res.output
    res = _ingest(src, "--out", tmp_path / "ds", "--camera", "a=a.mkv", "--offset", "a=0.5")
    assert res.exit_code == 0, res.output
    assert sorted(int(p.stem) for p in (tmp_path / "ds" / "images" / "a").iterdir()) == [
        500_000_000, 550_000_000, 600_000_000, 650_000_000]
