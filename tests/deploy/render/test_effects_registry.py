"""The effects package: the machinery in three modules (`base`, `registry`, `compose`) re-exported by the package,
and every other module one effect that the registry finds without being listed (torch-free)."""

from __future__ import annotations

import pkgutil

from aat_deploy.render import effects as fx
from aat_deploy.render.effects import base, compose, registry

MACHINERY = {"base", "registry", "compose"}


def test_the_package_re_exports_the_machinery():
    for mod in (base, compose, registry):
        for name in mod.__dict__:
            if name in fx.__all__:
                assert getattr(fx, name) is getattr(mod, name), name
    assert set(fx.__all__) <= set(vars(base)) | set(vars(compose)) | set(vars(registry))
    assert fx.NeedsTorch is base.NeedsTorch and fx.parse is registry.parse and fx.post_stack is compose.post_stack


def test_every_effect_is_one_file_found_by_the_registry():
    files = {m.name for m in pkgutil.iter_modules(fx.__path__)} - MACHINERY
    names = fx.names()  # imports every module of the package
    by_module: dict[str, list[str]] = {}
    for name in names:
        cls = type(fx.make(name))
        assert cls.__module__.startswith(fx.__name__ + "."), (name, cls.__module__)
        by_module.setdefault(cls.__module__.rpartition(".")[2], []).append(name)
    assert set(by_module) == files, "a module of the package that registers no effect, or an effect elsewhere"
    assert not set(by_module) & MACHINERY
    assert all(len(v) == 1 for v in by_module.values()), by_module  # one effect per file
    assert {m: v[0] for m, v in by_module.items()} == {m: m for m in files}  # the file is named after its effect
