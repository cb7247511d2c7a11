"""Every file a command reads is opened one safe way (:func:`ilcforce.tomlfile.read_regular`), and `tune`
never writes where it must not: issue 46's hangs, wrong robots and late refusals, each reproduced with
real files, FIFOs, links and command-line processes under a timeout (a hang fails the test instead of
holding it), then attacked with variants (other special files, other MJCF file attributes, a URDF's
mesh, other aliases of an input).

The tuning stores are made in-process with the stand-in cell (:func:`tunekit.fake_cell`): these tests
time files and processes, not physics. A `tune` rerun on a finished store runs no cell.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ilcforce.tomlfile import UnreadableFile, read_regular
from tunekit import ROOT, TINY, tiny_file, tuned

#: A hang guard, not a speed claim: each guarded command takes 2-10 s here (Python, numpy, MuJoCo and
#: optuna imports on 2 shared cores); a FIFO held every one of them forever before.
HANG = 240


#: The bound of every "in bounded time" check here. What these guard against is a block forever (a FIFO,
#: /dev/zero) or minutes of work (1e10 asset look-ups, a parse quadratic in 120,000 bodies); when the code
#: works each takes milliseconds to about a second on an idle machine. 30 s is far from both: a loaded
#: 2-core machine (CI) stretches the working case by a few times, never to 30 s, and a hang still fails.
HANG_GUARD = 30.0


def cli(*args, cwd=None) -> subprocess.CompletedProcess:
    """``ilcforce ARGS`` in a process of its own, killed after :data:`HANG` s (the test then fails)."""
    return subprocess.run([sys.executable, "-m", "ilcforce", *map(str, args)], capture_output=True, text=True,
                          timeout=HANG, cwd=cwd, env={**os.environ, "PYTHONPATH": str(ROOT)})


def one_error_line(result: subprocess.CompletedProcess, *needles: str) -> str:
    """The one error line of a refused command (exit 2, no traceback), holding every needle."""
    text = result.stderr + result.stdout
    assert result.returncode == 2, text
    assert "Traceback" not in text and len(result.stderr.strip().splitlines()) == 1, text
    for needle in needles:
        assert needle in result.stderr, result.stderr
    return result.stderr.strip()


def tune_again(tmp_path, *args):
    return cli("tune", tiny_file(tmp_path, TINY), "--results", tmp_path / "r", "--workers", "1", "-q", *args)


# ------------------------------------------------------------------------------------------------
# the one safe open


@pytest.fixture
def specials(tmp_path):
    """name -> a path that is no regular file, with the reason read_regular gives."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(tmp_path / "sock"))
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    (tmp_path / "zero").symlink_to("/dev/zero")
    (tmp_path / "folder").mkdir()
    yield {"fifo": (fifo, "is a FIFO (named pipe), not a regular file"),
           "socket": (tmp_path / "sock", "is a socket, not a regular file"),
           "dangling link": (tmp_path / "dangling", "is a symbolic link that leads nowhere"),
           "link loop": (tmp_path / "loop", "is a symbolic link that leads nowhere"),
           "link to /dev/zero": (tmp_path / "zero", "is a character device, not a regular file"),
           "/dev/zero": (Path("/dev/zero"), "is a character device, not a regular file"),
           "directory": (tmp_path / "folder", "is a directory"),
           "missing": (tmp_path / "missing", "does not exist"),
           "under a file": (Path(__file__) / "x", "does not exist")}
    sock.close()


def test_read_regular_refuses_every_special_file_at_once(specials, tmp_path):
    for name, (path, reason) in specials.items():
        start = time.monotonic()
        with pytest.raises(UnreadableFile) as caught:
            read_regular(path, 1 << 20)
        assert str(caught.value).startswith(reason), (name, str(caught.value))
        assert time.monotonic() - start < HANG_GUARD, name  # nothing waited on: a FIFO used to block forever
    plain = tmp_path / "plain"
    plain.write_bytes(b"x" * 100)
    assert read_regular(plain, 100) == b"x" * 100
    with pytest.raises(UnreadableFile, match="is larger than 99 bytes"):
        read_regular(plain, 99)
    link = tmp_path / "link"
    link.symlink_to(plain)
    assert read_regular(link, 100) == b"x" * 100
    with pytest.raises(UnreadableFile, match="^is a symbolic link$"):
        read_regular(link, 100, follow_links=False)


def test_every_toml_loader_refuses_special_files_in_bounded_time(specials, tmp_path):
    """The experiment, study and tuning loaders, and `simulate -c` through a FIFO (a process)."""
    from ilcforce.config import ConfigError
    from ilcforce.config_load import load_config
    from ilcforce.study.spec import StudyError, load_study
    from ilcforce.tune.spec import TuneError, load_tuning

    for name, (path, reason) in specials.items():
        for load, error in ((load_config, ConfigError), (load_study, StudyError), (load_tuning, TuneError)):
            with pytest.raises(error, match=reason.split(",")[0].replace("(", r"\(").replace(")", r"\)")):
                load(path)
    result = cli("simulate", "-c", specials["fifo"][0], "-n", "1")
    one_error_line(result, "is a FIFO (named pipe), not a regular file")


# ------------------------------------------------------------------------------------------------
# item 9: the tuning store's tuned.toml and heldout/


def test_a_fifo_at_tuned_toml_neither_hangs_validate_nor_tune_and_tune_repairs_it(tmp_path):
    first = tuned(tmp_path, TINY)
    sealed = (first.path / "tuned.toml").read_bytes()
    (first.path / "tuned.toml").unlink()
    os.mkfifo(first.path / "tuned.toml")
    refused = cli("validate", first.path)
    assert refused.returncode == 2 and "tuned.toml: not the tuned file the last run wrote (it is a FIFO" in \
        refused.stdout + refused.stderr, refused.stdout + refused.stderr
    again = tune_again(tmp_path)
    assert again.returncode == 0, again.stderr
    assert (first.path / "tuned.toml").is_file() and (first.path / "tuned.toml").read_bytes() == sealed
    assert cli("validate", first.path).returncode == 0


@pytest.mark.parametrize("target", ["/dev/zero", "outside copy"])
def test_a_link_at_tuned_toml_is_never_followed_and_tune_replaces_it(tmp_path, target):
    """A link to /dev/zero read until MemoryError; a link out of the store to a copy of the sealed text
    was followed, and `tune` then left it (the text matched) while `validate` kept asking for a rerun."""
    first = tuned(tmp_path, TINY)
    tuned_file = first.path / "tuned.toml"
    sealed = tuned_file.read_bytes()
    outside = tmp_path / "elsewhere.toml"
    outside.write_bytes(sealed)
    tuned_file.unlink()
    tuned_file.symlink_to(target if target.startswith("/") else outside)
    refused = cli("validate", first.path)
    text = refused.stdout + refused.stderr
    assert refused.returncode == 2 and "(it is a symbolic link); rerun `ilcforce tune`" in text, text
    again = tune_again(tmp_path)
    assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
    assert not tuned_file.is_symlink() and tuned_file.read_bytes() == sealed
    assert outside.read_bytes() == sealed  # the link's target is never written
    assert cli("validate", first.path).returncode == 0


def test_a_symlinked_heldout_folder_is_refused_like_trials(tmp_path):
    one, other = tuned(tmp_path, TINY, results="one"), tuned(tmp_path, TINY, results="two")
    before = sorted(p.name for p in (other.path / "heldout").iterdir())
    shutil.rmtree(one.path / "heldout")
    (one.path / "heldout").symlink_to(other.path / "heldout")
    for overwrite in (False, True):
        result = cli("tune", tiny_file(tmp_path, TINY), "--results", tmp_path / "one", "--workers", "1", "-q",
                     *(["--overwrite"] if overwrite else []))
        one_error_line(result, f"{one.path / 'heldout'}: not a folder of this store (a link or a file); move it away")
    assert sorted(p.name for p in (other.path / "heldout").iterdir()) == before  # never written through
    (one.path / "heldout").unlink()
    (one.path / "heldout").write_text("not a folder")
    one_error_line(tune_again_in(tmp_path, "one"), "heldout: not a folder of this store")


def tune_again_in(tmp_path, results):
    return cli("tune", tiny_file(tmp_path, TINY), "--results", tmp_path / results, "--workers", "1", "-q")


def test_a_folder_at_tuned_toml_is_refused_before_any_trial(tmp_path):
    first = tuned(tmp_path, TINY)
    (first.path / "tuned.toml").unlink()
    (first.path / "tuned.toml").mkdir()
    (first.path / "tuned.toml" / "mine").write_text("kept")
    one_error_line(tune_again(tmp_path), "tuned.toml: a folder where the store keeps its tuned file; move it away")
    refused = cli("validate", first.path)
    assert refused.returncode == 2 and "(it is a directory); move it away" in refused.stdout + refused.stderr
    assert (first.path / "tuned.toml" / "mine").read_text() == "kept"


# ------------------------------------------------------------------------------------------------
# item 10: what a model file names, checked before MuJoCo reads it; item 11: its physical numbers

MODELS = ROOT / "experiments" / "models"
ARM3 = (MODELS / "arm3.xml").read_text()
SERIAL2R_URDF = (MODELS / "serial2r.urdf").read_text()


def model(tmp_path: Path, text: str, name: str = "robot.xml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def with_asset(asset: str, text: str = ARM3) -> str:
    return text.replace("<worldbody>", f"<asset>{asset}</asset><worldbody>", 1)


def config_cli(path: Path, plant: str = "file_arm") -> subprocess.CompletedProcess:
    """`ilcforce config` of an experiment whose robot is the model file ``path`` (a 2-joint planar
    arm, ``file_arm``, or the 3-joint spatial one)."""
    experiment = "serial2r-model" if plant == "file_arm" else "arm3"
    return cli("config", "-c", experiment, "--set", f"plant.{plant}.path={path}")


def refused(path: Path, *needles: str, ee: str = "tool") -> str:
    """load_model's one line for ``path`` (in bounded time), holding every needle."""
    from ilcforce.plants.model_file import load_model

    start = time.monotonic()
    with pytest.raises(ValueError) as caught:
        load_model(path, ee)
    message = str(caught.value)
    assert time.monotonic() - start < HANG_GUARD, message
    assert "\n" not in message and "MuJoCo cannot read it" not in message, message
    for needle in needles:
        assert needle in message, message
    return message


def test_a_fifo_named_by_include_or_mesh_is_refused_by_the_command_in_bounded_time(tmp_path):
    """Both blocked MuJoCo's parser forever (an include at parse time, a mesh at compile time)."""
    os.mkfifo(tmp_path / "part.xml")
    os.mkfifo(tmp_path / "link.stl")
    included = model(tmp_path, ARM3.replace("<worldbody>", '<include file="part.xml"/><worldbody>'), "inc.xml")
    meshed = model(tmp_path, with_asset('<mesh name="m" file="link.stl"/>'), "mesh.xml")
    one_error_line(config_cli(included, "spatial_arm"), f"names {tmp_path / 'part.xml'}, which is a FIFO (named pipe)")
    one_error_line(config_cli(meshed, "spatial_arm"), f'<mesh file="link.stl">: {tmp_path / "link.stl"} is a FIFO')


def test_a_model_of_many_bodies_is_refused_before_the_parse(tmp_path):
    """120,000 empty bodies (10 MB) took MuJoCo 205 s; 2,000 would pass the size bound and the element
    bound but not the body bound; a replicate makes 10,000 of one."""
    from ilcforce.plants import model_refs

    many = "".join(f'<body name="b{i}"/>' for i in range(120_000))
    refused(model(tmp_path, f"<mujoco><worldbody>{many}</worldbody></mujoco>", "big.xml"),
            "more than 1,000 bodies")
    refused(model(tmp_path, ARM3.replace("<worldbody>", '<worldbody><replicate count="100" offset="1 0 0">'
                                         '<replicate count="100" offset="0 1 0"><body/></replicate></replicate>'),
                  "rep.xml"), "more than")
    sites = "".join("<site/>" for _ in range(model_refs.MAX_ELEMENTS))
    refused(model(tmp_path, ARM3.replace('<body name="tool" pos="0.34 0 0">',
                                         f'<body name="tool" pos="0.34 0 0">{sites}'), "sites.xml"),
            f"more than {model_refs.MAX_ELEMENTS:,} elements")
    compilers = "".join(f'<compiler meshdir="m{i}"/>' for i in range(10_000))
    textures = "".join(f'<texture name="t{i}" type="2d" file="t{i}.png"/>' for i in range(9_000))
    start = time.monotonic()
    refused(model(tmp_path, ARM3.replace("<worldbody>", f"{compilers}<asset>{textures}</asset><worldbody>"),
                  "dirs.xml"), f"more than {model_refs.MAX_DIRS} different meshdir")
    refused(model(tmp_path, ARM3.replace("<worldbody>", f"<asset>{textures}</asset><worldbody>"), "names.xml"),
            f"names more than {model_refs.MAX_ASSET_NAMES:,} asset files")
    assert time.monotonic() - start < HANG_GUARD  # 1e10 look-ups of every place an asset may be, before the bounds
    huge = tmp_path / "huge.xml"
    with huge.open("w") as handle:
        handle.write("<mujoco>" + " " * (model_refs.MAX_XML_BYTES + 1) + "</mujoco>")
    refused(huge, "is larger than the 4 MB of XML")
    start = time.monotonic()
    one_error_line(config_cli(tmp_path / "big.xml", "spatial_arm"), "more than 1,000 bodies")
    assert time.monotonic() - start < 60  # about 3 s: the process's imports; MuJoCo never parses it


def test_every_file_attribute_mujoco_follows_is_checked(tmp_path, specials):
    """The MJCF attributes that name a file (MuJoCo's schema, mj_printSchema): include, mesh, hfield,
    skin, texture and its six cube faces, and a model asset; each named as a FIFO, a socket, a link to
    /dev/zero, a folder or a dangling link is refused naming the attribute, never opened."""
    assets = {"include": '<include file="{f}"/>', "mesh": '<mesh name="m" file="{f}"/>',
              "hfield": '<hfield name="h" file="{f}"/>', "skin": '<skin file="{f}"/>',
              "texture": '<texture name="t" type="2d" file="{f}"/>',
              **{face: f'<texture name="c" type="cube" {face}="{{f}}"/>'
                 for face in ("fileright", "fileleft", "fileup", "filedown", "filefront", "fileback")},
              "model": '<model name="sub" file="{f}"/>'}
    for kind in ("fifo", "socket", "link to /dev/zero", "directory", "dangling link"):
        special, reason = specials[kind]
        for attribute, element in assets.items():
            text = element.format(f=special)
            text = (ARM3.replace("<worldbody>", text + "<worldbody>") if attribute == "include"
                    else with_asset(text))
            message = refused(model(tmp_path, text, f"{attribute}.xml"))
            assert str(special) in message and reason.split(",")[0].split(" (")[0] in message, (kind, attribute, message)


def test_a_mesh_in_a_meshdir_or_in_an_included_file_is_found_where_mujoco_looks(tmp_path):
    """MuJoCo looks for an asset under meshdir, beside the model and beside the file naming it (and an
    include beside the model or the including file): every such place that exists is checked."""
    (tmp_path / "meshes").mkdir()
    (tmp_path / "parts").mkdir()
    os.mkfifo(tmp_path / "meshes" / "link.stl")
    text = ARM3.replace('<compiler angle="radian"/>', '<compiler angle="radian" meshdir="meshes"/>')
    refused(model(tmp_path, with_asset('<mesh name="m" file="link.stl"/>', text)), "meshes/link.stl is a FIFO")
    (tmp_path / "parts" / "asset.xml").write_text('<mujoco><asset><mesh name="m" file="link.stl"/></asset></mujoco>')
    refused(model(tmp_path, text.replace("<worldbody>", '<include file="parts/asset.xml"/><worldbody>'), "i.xml"),
            "is a FIFO")
    (tmp_path / "parts" / "outer.xml").write_text('<mujoco><include file="inner.xml"/></mujoco>')
    os.mkfifo(tmp_path / "parts" / "inner.xml")
    refused(model(tmp_path, ARM3.replace("<worldbody>", '<include file="parts/outer.xml"/><worldbody>'), "o.xml"),
            "inner.xml, which is a FIFO")
    refused(model(tmp_path, ARM3.replace("<worldbody>", '<include file="loop.xml"/><worldbody>'), "loop.xml"),
            "includes itself")


def test_a_urdf_mesh_is_never_opened(tmp_path):
    """A URDF's geometry is deleted before compiling: a FIFO, /dev/zero or a missing file as its mesh
    changes nothing (the arm loads, at once)."""
    from ilcforce.plants.model_file import load_model

    os.mkfifo(tmp_path / "link.stl")
    for mesh in (tmp_path / "link.stl", "/dev/zero", tmp_path / "missing.stl"):
        text = SERIAL2R_URDF.replace('<link name="tool"/>', '<link name="tool"><visual><geometry><mesh filename="'
                                     f'{mesh}"/></geometry></visual><collision><geometry><mesh filename="{mesh}"/>'
                                     '</geometry></collision></link>')
        start = time.monotonic()
        assert load_model(model(tmp_path, text, "arm.urdf"), "tool").n == 2
        assert time.monotonic() - start < HANG_GUARD


def test_entities_oversized_images_sizes_and_deformables_are_refused(tmp_path):
    laughs = ('<?xml version="1.0"?><!DOCTYPE mujoco [<!ENTITY a "aaaaaaaaaa">'
              + "".join(f'<!ENTITY {chr(98 + i)} "{("&" + chr(97 + i) + ";") * 10}">' for i in range(8)) + "]>")
    refused(model(tmp_path, laughs + ARM3.split("-->", 1)[1].replace('name="tool"', 'name="&i;"'), "laughs.xml"),
            "declares the XML entity 'a'")
    png = tmp_path / "bomb.png"  # a header of 100,000 x 100,000 pixels: 30 GB once decoded
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0\0\0\rIHDR" + (100_000).to_bytes(4, "big") * 2 + bytes(20))
    refused(model(tmp_path, with_asset(f'<texture name="t" type="2d" file="{png}"/>'), "png.xml"),
            "is an image of more than 16,777,216 pixels")
    refused(model(tmp_path, with_asset('<texture name="t" type="2d" builtin="checker" width="100000" height="100000"/>'),
                  "checker.xml"), "more than 16,777,216 pixels")
    refused(model(tmp_path, ARM3.replace("<worldbody>", '<size nuser_body="100000000"/><worldbody>'), "size.xml"),
            '<size nuser_body="100000000"> is more than 1,000')
    refused(model(tmp_path, ARM3.replace("<worldbody>", '<size nkey="100000000"/><worldbody>'), "keys.xml"),
            '<size nkey="100000000"> is more than 1,000')
    refused(model(tmp_path, ARM3.replace("</worldbody>", '<flexcomp name="f" type="grid" count="1000 1000 1000" '
                                          'spacing="1 1 1" dim="3"/></worldbody>'), "flex.xml"),
            "<flexcomp> is a deformable body")


#: (what, the original text, its replacement, the line's element and words) in arm3.xml
NUMBERS = [
    ("NaN axis", 'name="shoulder" type="hinge" axis="0 -1 0"', 'name="shoulder" type="hinge" axis="0 nan 0"',
     "joint 'shoulder': axis 0 nan 0 is not finite"),
    ("zero axis", 'name="shoulder" type="hinge" axis="0 -1 0"', 'name="shoulder" type="hinge" axis="0 0 0"',
     "joint 'shoulder'"),
    ("inf position", '<body name="forearm" pos="0.35 0 0">', '<body name="forearm" pos="inf 0 0">',
     "body 'forearm': position inf 0 0 is not finite"),
    ("NaN euler", '<body name="forearm" pos="0.35 0 0">', '<body name="forearm" pos="0.35 0 0" euler="0 nan 0">',
     "body 'forearm': orientation"),
    ("NaN anchor", 'name="elbow" type="hinge"', 'name="elbow" pos="nan 0 0" type="hinge"', "joint 'elbow': anchor"),
    ("NaN reference", 'name="elbow" type="hinge"', 'name="elbow" ref="nan" type="hinge"', "joint 'elbow': reference"),
    ("NaN centre of mass", 'pos="0.16 0 0.005"', 'pos="nan 0 0.005"', "body 'upper_arm': centre of mass"),
    ("NaN site", '<body name="tool" pos="0.34 0 0">', '<body name="tool" pos="0.34 0 0"><site name="s" pos="nan 0 0"/>',
     "site 's': position nan 0 0"),
    ("negative mass of a fixed body", 'mass="0.25"', 'mass="-0.25"', "body 'tool': mass -0.25 kg is not a number > 0"),
    ("NaN mass", 'mass="0.25"', 'mass="nan"', "body 'tool': mass nan kg"),
    ("inf mass", 'mass="2.0"', 'mass="inf"', "body 'upper_arm': mass inf kg"),
    ("1e308 mass", 'mass="2.0"', 'mass="1e308"', "body 'upper_arm': mass 1e+308 kg is not a number > 0 and at most 1e+06"),
    ("NaN in a full inertia", 'fullinertia="1e-4 1.5e-4 1.5e-4 0 0 0"', 'fullinertia="nan 1.5e-4 1.5e-4 0 0 0"',
     "body 'tool': inertia nan"),
    ("negative inertia", 'fullinertia="1e-4 1.5e-4 1.5e-4 0 0 0"', 'fullinertia="1e-4 -1.5e-4 1.5e-4 0 0 0"',
     "body 'tool': inertia 0.0001 0 0 0 -0.00015 0 0 0 0.00015 is not positive definite"),
    ("triangle inequality", 'fullinertia="1e-4 1.5e-4 1.5e-4 0 0 0"', 'fullinertia="1e-4 1e-4 1.5e-3 0 0 0"',
     "body 'tool': principal moments of inertia 0.0001 0.0001 0.0015 kg m^2 break the triangle inequality"),
    ("a massless body with inertia", 'mass="0.25"', 'mass="0"', "body 'tool': mass 0 with inertia"),
]


@pytest.mark.parametrize("what, old, new, expected", NUMBERS, ids=[n[0] for n in NUMBERS])
def test_every_physical_number_of_an_mjcf_is_checked_naming_the_element(tmp_path, what, old, new, expected):
    assert old in ARM3
    refused(model(tmp_path, ARM3.replace(old, new, 1)), expected)


URDF_NUMBERS = [
    ("NaN origin", '<origin xyz="0.35 0 0"', '<origin xyz="nan 0 0"', "body 'link2': position nan 0 0"),
    ("NaN rpy", '<origin xyz="0.35 0 0" rpy="0 0 0"/>', '<origin xyz="0.35 0 0" rpy="0 nan 0"/>',
     "body 'link2': orientation"),
    ("NaN axis", '<axis xyz="0 -1 0"/>\n  </joint>\n  <link name="link2">',
     '<axis xyz="0 nan 0"/>\n  </joint>\n  <link name="link2">', "joint 'joint2': axis 0 nan 0"),
    ("negative mass", '<mass value="0.9"/>', '<mass value="-0.9"/>', "body 'link2': mass -0.9 kg"),
    ("inf mass", '<mass value="0.9"/>', '<mass value="inf"/>', "body 'link2': mass inf kg"),
    ("NaN inertia", 'iyy="6.75e-3"', 'iyy="nan"', "body 'link2': inertia"),
]


@pytest.mark.parametrize("what, old, new, expected", URDF_NUMBERS, ids=[n[0] for n in URDF_NUMBERS])
def test_every_physical_number_of_a_urdf_is_checked_naming_the_element(tmp_path, what, old, new, expected):
    assert old in SERIAL2R_URDF
    refused(model(tmp_path, SERIAL2R_URDF.replace(old, new, 1), "arm.urdf"), expected)


def test_config_and_simulate_refuse_a_nan_model_with_one_line(tmp_path):
    """They crashed with a LinAlgError traceback; a negative mass loaded as 0 and a NaN mass ran into
    "diverged at t = 0" stored as a result."""
    nan_origin = model(tmp_path, SERIAL2R_URDF.replace('<origin xyz="0.35 0 0"', '<origin xyz="nan 0 0"'), "nan.urdf")
    one_error_line(config_cli(nan_origin), "body 'link2': position nan 0 0 is not finite")
    nan_mass = model(tmp_path, SERIAL2R_URDF.replace('<mass value="0.9"/>', '<mass value="nan"/>'), "mass.urdf")
    result = cli("simulate", "-c", "serial2r-model", "--set", f"plant.file_arm.path={nan_mass}", "-n", "1",
                 "--results", tmp_path / "results")
    one_error_line(result, "body 'link2': mass nan kg")
    assert not list((tmp_path / "results").rglob("*.h5")) if (tmp_path / "results").exists() else True


def test_the_shipped_models_pass_every_check():
    from ilcforce.plants.model_file import load_model, referenced_files

    for name in ("serial2r.xml", "serial2r.urdf", "arm3.xml", "arm3.urdf"):
        assert load_model(name, "tool").n in (2, 3)
        assert referenced_files(name) == [MODELS / name]


# ------------------------------------------------------------------------------------------------
# items 13 and 14: tune -o


def test_tune_output_in_a_read_only_folder_is_refused_before_the_first_trial(tmp_path):
    """It was refused only after every trial and held-out run. A read-only file system (a tmpfs mounted
    read-only in a mount namespace of its own, when this runs as root: root writes any folder whatever
    its mode) or, for anyone else, a folder of mode 555."""
    folder = tmp_path / "ro"
    folder.mkdir()
    command = [sys.executable, "-m", "ilcforce", "tune", str(tiny_file(tmp_path, TINY)), "--results",
               str(tmp_path / "r"), "--workers", "1", "-q"]
    if os.geteuid() == 0:
        if shutil.which("unshare") is None or subprocess.run(
                ["unshare", "-m", "true"], capture_output=True).returncode != 0:
            pytest.skip("root without mount namespaces: no read-only folder to write in")
        wrapped = ["unshare", "-m", "sh", "-c", 'mount -t tmpfs -o ro tmpfs "$0" && exec "$@"', str(folder)]
        run = lambda *args: subprocess.run([*wrapped, *command, *args], capture_output=True, text=True,  # noqa: E731
                                           timeout=HANG, env={**os.environ, "PYTHONPATH": str(ROOT)})
        reason = "a read-only file system"
    else:
        folder.chmod(0o555)
        run = lambda *args: subprocess.run([*command, *args], capture_output=True, text=True,  # noqa: E731
                                           timeout=HANG, env={**os.environ, "PYTHONPATH": str(ROOT)})
        reason = "permission denied"
    for output in (folder / "tuned.toml", folder / "sub" / "tuned.toml"):
        start = time.monotonic()
        result = run("-o", output)
        one_error_line(result, f"-o {output}: cannot write in {folder} ({reason})")
        assert not (tmp_path / "r").exists()  # no store made, no trial run
        assert time.monotonic() - start < 60
    folder.chmod(0o755)


def test_tune_output_never_replaces_an_input_of_the_run_under_any_name(tmp_path):
    """`tune t.toml -o <t.toml's experiment> --overwrite` replaced the experiment, and every later `tune
    t.toml` was refused. The experiment (by a copy of its own here), the tuning file, the model file,
    and each through a hard link, a `./x/../x` path and a path through a linked folder."""
    from ilcforce.tune import TuneError, load_tuning, run_tuning

    from tunekit import fake_cell

    experiment = tmp_path / "exp.toml"
    experiment.write_text((ROOT / "experiments" / "paper.toml").read_text())
    text = TINY.replace(str(ROOT / "experiments" / "paper.toml"), str(experiment))
    tuning_file = tiny_file(tmp_path, text)
    before = experiment.read_bytes()
    result = cli("tune", tuning_file, "--results", tmp_path / "r", "--workers", "1", "-q", "-o", experiment,
                 "--overwrite")
    one_error_line(result, f"-o {experiment}: is an input of this run: the tuning's experiment file")
    assert experiment.read_bytes() == before and not (tmp_path / "r").exists()
    os.link(experiment, tmp_path / "hard.toml")
    (tmp_path / "sub").mkdir()
    (tmp_path / "linked").symlink_to(tmp_path)
    tuning = load_tuning(tuning_file)
    aliases = {tmp_path / "hard.toml": "the tuning's experiment file",
               tmp_path / "sub" / ".." / "exp.toml": "the tuning's experiment file",
               tmp_path / "linked" / "exp.toml": "the tuning's experiment file",
               tmp_path / "linked" / "tiny.toml": "the tuning file itself"}
    for output, what in aliases.items():
        with pytest.raises(TuneError, match=f"is (an input of this run: )?{what}"):
            run_tuning(tuning, tmp_path / "r", workers=1, cell_function=fake_cell, output=output, overwrite=True)
    assert experiment.read_bytes() == before and tuning_file.read_text() == text


def test_tune_output_never_replaces_the_model_file_or_a_file_it_includes(tmp_path):
    from ilcforce.tune import TuneError, load_tuning, run_tuning
    from ilcforce.tune.output import run_inputs

    from tunekit import fake_cell

    (tmp_path / "part.toml").write_text("<mujoco><size nkey=\"1\"/></mujoco>\n")  # an include named .toml
    robot = model(tmp_path, (MODELS / "serial2r.xml").read_text().replace(
        "<worldbody>", '<include file="part.toml"/><worldbody>'), "robot.xml")
    text = TINY.replace(str(ROOT / "experiments" / "paper.toml"), str(ROOT / "experiments" / "serial2r-model.toml"))
    text = text.replace('"reference.duration" = 0.2', f'"reference.duration" = 0.2\n"plant.file_arm.path" = "{robot}"')
    tuning = load_tuning(tiny_file(tmp_path, text))
    assert {p for _, p in run_inputs(tuning)} >= {robot, tmp_path / "part.toml"}
    for output, what in ((tmp_path / "part.toml", "a file the model file"),):  # MuJoCo reads a model named .xml or .urdf
        with pytest.raises(TuneError, match=f"is an input of this run: {what}"):
            run_tuning(tuning, tmp_path / "r", workers=1, cell_function=fake_cell, output=output, overwrite=True)


def test_a_nan_no_check_reads_is_refused_too_and_mujocos_warning_is_not_printed(tmp_path, capfd, monkeypatch):
    """A NaN in a joint's damping (not part of the rigid-body model): MuJoCo printed a warning, wrote it
    to MUJOCO_LOG.TXT in the working directory, and loaded."""
    from ilcforce.plants.model_file import load_model

    monkeypatch.chdir(tmp_path)
    refused(model(tmp_path, ARM3.replace('name="elbow" type="hinge"', 'name="elbow" damping="nan" type="hinge"')),
            "MuJoCo warns: XML contains a 'NaN'")
    assert load_model(MODELS / "arm3.xml", "tool").n == 3
    out, err = capfd.readouterr()
    assert "NaN" not in out + err and not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_an_inertia_from_geoms_is_checked_as_compiled(tmp_path):
    """A body without <inertial> takes its mass from its geoms: a density of 1e300 made a finite,
    absurd mass no check of the file's own numbers sees."""
    tool_inertial = '<inertial pos="-0.02 0 0" mass="0.25" fullinertia="1e-4 1.5e-4 1.5e-4 0 0 0"/>'
    tool_geom = '<geom type="cylinder" fromto="-0.04 0 0 0 0 0" size="0.02" contype="0" conaffinity="0"/>'
    assert tool_inertial in ARM3 and tool_geom in ARM3
    bare = ARM3.replace(tool_inertial, "")
    dense = bare.replace(tool_geom, tool_geom.replace('size="0.02"', 'size="0.02" density="1e300"'))
    refused(model(tmp_path, dense), "body 'tool': mass 5.02655e+295 is out of bounds (finite, at least 0, at most 1e+06")
    from ilcforce.plants.model_file import load_model

    assert load_model(model(tmp_path, bare, "bare.xml"), "tool").n == 3  # a density of water: a mass, loaded


def test_the_scan_refuses_no_file_mujoco_reads_and_counts_a_urdf_model_asset(tmp_path):
    """expat reads as MuJoCo does: a windows-1252 declaration over a stray byte, and an entity MuJoCo
    leaves alone (&nbsp;), still load; a <model file> that is a URDF of 120,000 links is counted by
    its links, not let through as an MJCF of no body."""
    from ilcforce.plants.model_file import load_model

    body = ARM3.split("-->", 1)[1]
    latin = tmp_path / "latin.xml"
    latin.write_bytes(b'<?xml version="1.0" encoding="windows-1252"?><!-- caf\xe9 -->' + body.encode())
    assert load_model(latin, "tool").n == 3
    assert load_model(model(tmp_path, body.replace('<mujoco model="arm3">', '<mujoco model="arm3&nbsp;">'),
                            "nbsp.xml"), "tool").n == 3
    model(tmp_path, '<robot name="r">' + "".join(f'<link name="l{i}"/>' for i in range(120_000)) + "</robot>",
          "many.urdf")
    refused(model(tmp_path, with_asset(f'<model name="u" file="{tmp_path / "many.urdf"}"/>'), "sub.xml"),
            "many.urdf: more than 1,000 bodies")
