"""One error root: every exception class defined in `aat_deploy` and `training` derives from
`aat_deploy.errors.AatError` (a ValueError), so `except AatError` catches exactly aat's own errors. Classes that
also derive from another built-in keep it (callers catching RuntimeError or ImportError still do). The one exception
to the rule is a signal, not an error: `Interrupted` (a KeyboardInterrupt) must never be caught by the
`except ValueError` of a batch that goes on after a bad capture."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

from aat_deploy.errors import AatError

NOT_ERRORS = {"aat_deploy.interrupt.Interrupted"}  # KeyboardInterrupt: stops the run, whatever catches ValueError
KEEPS = {"aat_deploy.diagnose.session.DiagnoseError": RuntimeError, "training.chain.runner.ChainError": RuntimeError,
         "aat_deploy.render.effects.base.NeedsTorch": RuntimeError,
         "aat_deploy.extensions.ExtensionUnavailable": ImportError}


def _exception_classes(package: str) -> dict[str, type]:
    pkg = importlib.import_module(package)
    found = {}
    for m in pkgutil.walk_packages(pkg.__path__, package + "."):
        mod = importlib.import_module(m.name)
        for c in vars(mod).values():
            if inspect.isclass(c) and issubclass(c, BaseException) and c.__module__ == m.name:
                found[f"{m.name}.{c.__qualname__}"] = c
    return found


@pytest.mark.parametrize("package", ["aat_deploy", "training"])
def test_every_exception_class_derives_from_aat_error(package):
    if package == "training":
        pytest.importorskip("torch", reason="the training package needs the train extra (torch)")
    classes = _exception_classes(package)
    assert len(classes) >= (10 if package == "aat_deploy" else 5)  # the walk sees the package's errors
    stray = sorted(n for n, c in classes.items() if not issubclass(c, AatError) and n not in NOT_ERRORS)
    assert stray == [], f"derive these from aat_deploy.errors.AatError: {stray}"
    for name, base in KEEPS.items():
        if name in classes:
            assert issubclass(classes[name], base), name


def test_the_root_is_a_value_error_and_interrupts_are_not_errors():
    from aat_deploy.cli.common import Interrupted

    assert issubclass(AatError, ValueError)
    assert not issubclass(Interrupted, Exception)
    with pytest.raises(AatError, match="^x.json: bad$"):
        from aat_deploy.lens.io import LensFileError

        raise LensFileError("x.json: bad")
