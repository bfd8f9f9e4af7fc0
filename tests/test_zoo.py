"""The model zoo (simshear_gym/models/zoo.py) is the one owner of the shipped models' paths, and its functions work.

The rule the first test enforces, over every module of the package but ``models/zoo.py`` (code, help texts and
docstrings alike): no module

- writes a fragment of a shipped path: ``models/weights``, ``weights/posenet|policies|student``, a shipped
  translator's file name (``shpix2pix_surface.pt``, ``pix2pix_edge.onnx``, ...) or a shipped policy's folder
  (``policies/tracking_ppo``, ...);
- joins a path with one of the zoo's folder names as a string (``... / "weights"``, ``/ "posenet"``,
  ``/ "policies"``, ``/ "student"``);
- defines its own weights-folder constant (a name like ``WEIGHTS_DIR``, ``POSENET_WEIGHTS_DIR``, ``STUDENT_DIR``).

Such a module asks the zoo instead (``translator_weights``, ``posenet_weights``, ``policy_folder``, ...).
"""

from __future__ import annotations

import ast
import json
import re
from pathlib import Path

import pytest

from simshear_gym.models import zoo

PACKAGE = Path(__file__).resolve().parents[1] / "simshear_gym"
OWNER = PACKAGE / "models" / "zoo.py"
PATH_FRAGMENT = re.compile(r"models/weights|weights/(posenet|policies|student)|\b(sh)?pix2pix_(surface|edge)\.(pt|onnx)"
                           r"|policies/\w+_ppo")
FOLDER_NAMES = {"weights", "posenet", "policies", "student"}
FOLDER_CONSTANT = re.compile(r"^\w*(WEIGHTS|STUDENT|POSENET|POLICY|POLICIES)\w*_DIR$")


def _violations(path: Path) -> list[str]:
    text = path.read_text()
    found = [f"line {text.count(chr(10), 0, m.start()) + 1}: {m.group(0)!r}" for m in PATH_FRAGMENT.finditer(text)]
    for node in ast.walk(ast.parse(text, str(path))):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
            for side in (node.left, node.right):
                if isinstance(side, ast.Constant) and side.value in FOLDER_NAMES:
                    found.append(f"line {node.lineno}: joins {side.value!r}")
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
            node, ast.AnnAssign) else []
        for target in targets:
            if isinstance(target, ast.Name) and FOLDER_CONSTANT.match(target.id):
                found.append(f"line {node.lineno}: defines {target.id}")
    return found


def test_no_module_but_the_zoo_names_a_shipped_weight_path():
    modules = [path for path in sorted(PACKAGE.rglob("*.py")) if path != OWNER]
    assert len(modules) > 50
    found = [f"{path.relative_to(PACKAGE)}: {v}" for path in modules for v in _violations(path)]
    assert not found, "shipped weight paths named outside models/zoo.py:\n" + "\n".join(found)
    assert _violations(OWNER), "the rule finds nothing even in the zoo: it has gone blind"


def test_the_zoo_is_torch_free_at_import():
    import subprocess
    import sys

    code = "import sys, simshear_gym.models.zoo; print(sorted({'torch', 'pybullet'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_shipped_models_are_found_by_name():
    translators = zoo.shipped_translators()
    for contact in ("surface", "edge"):
        for arch in ("shpix2pix", "pix2pix"):
            path = zoo.translator_weights(contact, arch)
            assert path.is_file() and translators[(arch, contact)] == path
            assert path == zoo.translator_file(arch, contact)
    assert {"surface", "edge", "colift", "colift_heavy"} <= set(zoo.shipped_posenets())
    for name in zoo.shipped_posenets():
        assert zoo.posenet_weights(name).is_file() and zoo.posenet_weights(name) == zoo.posenet_file(name)
    assert {"tracking_ppo", "colift_ppo", "edge_ppo"} <= set(zoo.shipped_policies())
    assert (zoo.policy_folder("tracking_ppo") / "model.pt").is_file()
    assert zoo.estimator_file("translator_shpix2pix_edge") == zoo.translator_weights("edge")
    assert zoo.estimator_file("posenet_colift") == zoo.posenet_weights("colift")
    assert zoo.translator_file("pix2pix", "edge", Path("x")) == Path("x") / zoo.translator_file("pix2pix", "edge").name


@pytest.mark.parametrize(("call", "message"), [
    (lambda: zoo.translator_weights("cylinder"), r"no shipped shpix2pix translator for 'cylinder' contacts .*shipped: "
                                                 r"\[\('pix2pix', 'edge'\)"),
    (lambda: zoo.translator_weights("surface", "cyclegan"), r"no shipped cyclegan translator for 'surface'"),
    (lambda: zoo.posenet_weights("cylinder"), r"no shipped posenet for 'cylinder' contacts .*shipped: \[.*'colift'"),
    (lambda: zoo.policy_folder("walk_ppo"), r"no shipped policy 'walk_ppo' .*shipped: \[.*'tracking_ppo'"),
])
def test_a_bad_name_is_one_error_naming_the_value_and_the_choices(call, message):
    with pytest.raises(FileNotFoundError, match=message):
        call()


def test_a_bad_estimator_name_is_one_error():
    with pytest.raises(ValueError, match="must start with 'translator_' or 'posenet_', got 'gdnn_surface'"):
        zoo.estimator_file("gdnn_surface")


def test_the_student_folder_is_looked_up_when_asked(tmp_path, monkeypatch):
    monkeypatch.setattr(zoo, "STUDENT_DIR", tmp_path)
    with pytest.raises(FileNotFoundError, match=r"no shipped student shpix2pix translator for 'edge'.*shipped: \[\]"):
        zoo.translator_weights("edge", student=True)
    (tmp_path / "shpix2pix.pt").write_bytes(b"")  # <arch>.pt: both contact types
    assert zoo.translator_weights("edge", student=True) == tmp_path / "shpix2pix.pt"
    assert zoo.translator_weights("surface", student=True) == tmp_path / "shpix2pix.pt"


def test_sensor_json_round_trip(tmp_path):
    tactip = {"dome_radius_mm": 20.0}
    path = zoo.write_sensor(tmp_path, "lab_tip", "configs/lab_tip.toml", "smoke", tactip,
                            translators={"surface": "translator/a/best.pt"},
                            posenets={"surface": "posenet/b/best.pt"}, variables=["depth_mm"])
    assert path == tmp_path / zoo.SENSOR_FILE
    assert json.loads(path.read_text())["variables"] == ["depth_mm"]
    for spec in (path, tmp_path):
        models = zoo.load_sensor(spec)
        assert (models.name, models.tactip) == ("lab_tip", tactip)
        assert models.translator("surface") == str(tmp_path / "translator/a/best.pt")
        assert models.posenet("surface") == str(tmp_path / "posenet/b/best.pt")
    with pytest.raises(ValueError, match="sensor 'lab_tip' has no GDNN for 'edge' contacts; it has \\['surface'\\]"):
        models.posenet("edge")


def test_a_sensor_json_that_is_not_one_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no sensor models at"):
        zoo.load_sensor(tmp_path)
    (tmp_path / zoo.SENSOR_FILE).write_text(json.dumps({"sensor": "x"}))
    with pytest.raises(ValueError, match="not a sensor file of simshear pipeline run"):
        zoo.load_sensor(tmp_path)
