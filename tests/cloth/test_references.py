"""The naming scheme of the numba kernels and their numpy references: every public kernel of a
``*_kernels`` module has a plain numpy reference named ``<kernel>_reference`` in the same subpackage
(the tests holding the two equal are in test_solver.py, test_collision.py, test_driver.py and
test_limb_clearance.py), and no function of the package picks its implementation by a ``backend``
argument."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from types import ModuleType

import cloth_client

#: Public kernels whose reference carries another name: helpers exercised through the kernels that
#: call them, and kernels run by a public function whose reference is named after that function.
OTHER_REFERENCE = {
    "capsule_geometry": None,  # the table round_cone / penetration / collide measure against
    "round_cone_geo": None,
    "spring_vector": None,
    "clear_limbs": "clear_limbs_track_reference",  # limb_clearance.clear_limbs_track runs the kernel
}


def _modules() -> list[ModuleType]:
    names = [m.name for m in pkgutil.walk_packages(cloth_client.__path__, "cloth_client.")
             if not m.name.startswith("cloth_client.app")]  # the app imports pyrender / zenoh
    return [importlib.import_module(n) for n in names if n != "cloth_client.__main__"]


def test_every_kernel_has_a_reference_beside_it() -> None:
    modules = _modules()
    kernels = [m for m in modules if m.__name__.endswith("_kernels")]
    assert len(kernels) >= 8
    missing = []
    for mod in kernels:
        subpackage = mod.__name__.rsplit(".", 1)[0]
        references = {name for m in modules if m.__name__.startswith(subpackage + ".")
                      and not m.__name__.endswith("_kernels") for name in vars(m) if name.endswith("_reference")}
        for name in mod.__all__:
            if not callable(getattr(mod, name)) or name.isupper():
                continue
            want = OTHER_REFERENCE.get(name, f"{name}_reference")
            if want is not None and want not in references:
                missing.append(f"{mod.__name__}.{name}: no {want} in {subpackage}")
    assert not missing, missing


def test_no_backend_arguments_and_no_np_suffixes() -> None:
    offenders = []
    for mod in _modules():
        for name, obj in vars(mod).items():
            if getattr(obj, "__module__", None) != mod.__name__:
                continue
            if name.endswith("_np"):
                offenders.append(f"{mod.__name__}.{name}")
            functions = [obj] if inspect.isfunction(obj) else \
                [f for f in vars(obj).values() if inspect.isfunction(f)] if inspect.isclass(obj) else []
            for f in functions:
                if "backend" in inspect.signature(f).parameters:
                    offenders.append(f"{mod.__name__}.{f.__qualname__}(backend=...)")
    assert not offenders, offenders
