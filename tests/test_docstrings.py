"""Every public function documents its parameters and return value (numpydoc)."""

import importlib
import inspect

import pytest

MODULES = [
    "needlekit.geometry",
    "needlekit.needle",
    "needlekit.anatomy.fields",
    "needlekit.anatomy.scene",
    "needlekit.anatomy.clearance",
    "needlekit.anatomy.primitives",
    "needlekit.anatomy.voxel",
    "needlekit.anatomy.mesh",
    "needlekit.io.meshes",
    "needlekit.anatomy.summary",
    "needlekit.anatomy.occupancy",
    "needlekit.anatomy.needle_body",
    "needlekit.planning.straight.deformation",
    "needlekit.planning.straight.displacement_grid",
    "needlekit.planning.steerable.problem",
    "needlekit.planning.steerable.plan",
    "needlekit.planning.steerable.goal",
    "needlekit.planning.steerable.verify",
    "needlekit.planning.steerable.validity",
    "needlekit.planning.steerable.result",
    "needlekit.planning.steerable.rcs",
    "needlekit.planning.steerable.solve",
    "needlekit.planning.steerable.rrt",
    "needlekit.planning.steerable.sweep",
    "needlekit.scenario.problems",
    "needlekit.batch",
    "needlekit.planning.steerable.cost",
    "needlekit.report.sweep_report",
    "needlekit.report.html_page",
    "needlekit.report.straight_figures",
    "needlekit.report.straight_report",
    "needlekit.studies.sweep_study",
    "needlekit.control.dq",
    "needlekit.control.panda",
    "needlekit.control.vfi",
    "needlekit.control.qp",
    "needlekit.control.controller",
    "needlekit.control.parameters",
    "needlekit.control.adaptation",
    "needlekit.control.em",
    "needlekit.control.procedure",
    "needlekit.io.plans",
    "needlekit.io.markups",
    "needlekit.io.files",
    "needlekit.io.poses",
    "needlekit.io.volumes",
    "needlekit.io.medrad",
    "needlekit.scenario.loading",
    "needlekit.scenario.results",
    "needlekit.records",
    "needlekit.provenance",
    "needlekit.planning.options",
    "needlekit.planning.steerable.sweep_result",
    "needlekit.planning.steerable.dynamic_record",
    "needlekit.planning.straight.coverage",
    "needlekit.planning.straight.problem",
    "needlekit.planning.straight.cfrw",
    "needlekit.planning.straight.entry",
    "needlekit.planning.straight.sequence",
    "needlekit.planning.straight.planner",
    "needlekit.planning.straight.verify",
    "needlekit.planning.straight.ablation",
    "needlekit.planning.steerable.search",
    "needlekit.anatomy.voxel_connectivity",
    "needlekit.planning.interface",
    "needlekit.planning.registry",
    "needlekit.anatomy.voxel_local",
    "needlekit.io.medrad_paths",
    "needlekit.control.schedule",
    "needlekit.planning.result",
    "needlekit.geometry.segments",
    "needlekit.geometry.segment_mesh",
    "needlekit.anatomy.voxel_clearance",
    "needlekit.planning.straight.approach",
    "needlekit.report.approach_report",
    "needlekit.studies.liver_study",
]


def _public(module_name):
    mod = importlib.import_module(module_name)
    for name in mod.__all__:
        obj = getattr(mod, name)
        if inspect.isfunction(obj):
            yield name, obj
        elif inspect.isclass(obj) and obj.__module__ == mod.__name__:
            for meth_name, meth in vars(obj).items():
                if inspect.isfunction(meth) and not meth_name.startswith("_"):
                    yield f"{name}.{meth_name}", meth


PUBLIC = [(m, n, f) for m in MODULES for n, f in _public(m)]


@pytest.mark.parametrize(("module", "name", "fn"), PUBLIC, ids=[f"{m}.{n}" for m, n, _ in PUBLIC])
def test_public_function_has_numpydoc_sections(module, name, fn):
    doc = inspect.getdoc(fn) or ""
    assert "Returns\n-------" in doc or "Yields\n------" in doc, (
        f"{module}.{name}: no Returns section"
    )
    params = [p for p in inspect.signature(fn).parameters if p not in ("self", "cls")]
    if params:
        assert "Parameters\n----------" in doc, f"{module}.{name}: no Parameters section"
    # functions of arrays state the shapes of what they take and give
    if "ndarray" in doc or "array_like" in doc:
        assert "shape" in doc, f"{module}.{name}: arrays without shapes"
