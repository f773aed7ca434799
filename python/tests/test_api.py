"""The module's surface: every public name documented, and the stubs in step with the module."""
import ast
import inspect
import pathlib

import evkit

STUB = pathlib.Path(evkit.__file__).with_name("__init__.pyi")


def public_names():
    return {n for n in dir(evkit) if not n.startswith("_")}


def stub_names():
    tree = ast.parse(STUB.read_text())
    names = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return {n for n in names if not n.startswith("_")}


def test_stubs_cover_the_module():
    aliases = {"EventsLike", "ImageLike", "PathLike"}  # the stubs' own type aliases
    tree = ast.parse(STUB.read_text())
    assigned = {t.id for n in tree.body if isinstance(n, ast.Assign) for t in n.targets}
    assert aliases <= assigned
    assert public_names() == stub_names()


def test_stub_methods_exist():
    tree = ast.parse(STUB.read_text())
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            cls = getattr(evkit, node.name)
            for item in node.body:
                if isinstance(item, ast.FunctionDef) and not item.name.startswith("__"):
                    assert hasattr(cls, item.name), f"{node.name}.{item.name} is stubbed but absent"


def test_everything_is_documented():
    for name in public_names():
        obj = getattr(evkit, name)
        if inspect.ismodule(obj) or isinstance(obj, str):
            continue
        assert (obj.__doc__ or "").strip(), f"evkit.{name} has no docstring"
    assert evkit.read.__doc__.startswith("read(path")  # the signature, for help()
    assert evkit.Error.__module__ == "evkit" and issubclass(evkit.Error, ValueError)
    assert issubclass(evkit.FileError, evkit.Error) and issubclass(evkit.FileError, OSError)
    assert evkit.Recording.__module__ == "evkit" and issubclass(evkit.Recording, evkit.Events)
