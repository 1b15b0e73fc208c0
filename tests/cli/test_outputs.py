"""Every command refuses an output that is, or lies inside, one of its inputs."""



from skintopo.cli import main
from skintopo.synth import make_surface, preset_spec


def test_every_command_refuses_an_output_equal_to_or_inside_an_input(tmp_path, capsys):
    z = make_surface(preset_spec("forehead-low", size_px=64), seed=1).height
    a, b = tmp_path / "a.x3p", tmp_path / "b.x3p"
    z.save(a)
    z.save(b)
    original = a.read_bytes()
    assert main(["evaluate", str(a), str(b), "-o", str(a), "--overwrite", "-q"]) == 2
    assert "would overwrite or lie inside the input" in capsys.readouterr().err and a.read_bytes() == original
    assert main(["evaluate", str(a), str(b), "-o", str(tmp_path), "-q"]) == 2
    assert "is a folder" in capsys.readouterr().err
    images = tmp_path / "spheres"
    images.mkdir()
    (images / "s1.png").write_bytes(b"x")
    assert main(["calibrate", "lights", str(images / "s1.png"), "-o", str(images / "s1.png"), "--overwrite", "-q"]) == 2
    assert "would overwrite" in capsys.readouterr().err and (images / "s1.png").read_bytes() == b"x"
    measured = tmp_path / "m"
    assert main(["wrinkles", str(a), "-o", str(measured), "-q"]) == 0
    for command in (["measure", str(measured), "-o", str(measured / "inner")], ["wrinkles", str(measured), "-o", str(measured)],
                    ["compare", str(measured), str(b), "-o", str(measured)]):
        listing = sorted(p.name for p in measured.rglob("*"))
        assert main([*command, "--overwrite", "-q"]) == 2, command
        assert "overlaps the input" in capsys.readouterr().err
        assert sorted(p.name for p in measured.rglob("*")) == listing
