"""The package layout: stages import only from stages above them, and no module imports itself
back through others (read from the source, function-level imports included)."""

import ast
import pathlib

import pytest

import kosmos_jax

ROOT = pathlib.Path(kosmos_jax.__file__).parent
# Top to bottom; a module may import from its own entry or any entry above it.
LAYERS = (
    ("geometry", "grasp_text", "publish", "jax_platforms", "commands"),  # commands: how entry points read flags
    ("metrics",),
    ("sources",),  # readers of the photo datasets (Cornell, Jacquard, synthetic scenes) and their splits
    ("augment",),
    ("annotators",),
    ("instruct",),
    ("text",),
    ("dataset",),  # INSTRUCT-GRASP built from a source: views, samples, text, tokens, shards
    ("models", "baselines"),
    ("scoring",),  # above train: the trainer scores decoded grasps; scoring never imports train
    ("workdir",),  # the run layer: a workdir's files, model, checkpoints (params-only restore), export
    ("train",),
    ("evaluate",),
    ("diagnostics",),  # why a run scores what it scores: answer errors, part oracles, image use, probes
    ("experiments", "predict"),  # experiments: train + evaluate per fold; predict: one grasp from a trained run
    ("demo", "cli"),
)
LEVEL = {name: level for level, names in enumerate(LAYERS) for name in names}


def module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: pathlib.Path, known: set[str]) -> set[str]:
    """The kosmos_jax modules `path` imports (`from pkg import name` counts as pkg.name when that is a module)."""
    found = set()
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("kosmos_jax"))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            if not base.startswith("kosmos_jax"):
                continue
            for alias in node.names:
                candidate = f"{base}.{alias.name}"
                found.add(candidate if candidate in known else base)
    return found


def graph() -> dict[str, set[str]]:
    files = {module_name(p): p for p in ROOT.rglob("*.py")}
    known = set(files)
    return {name: imported_modules(path, known) - {name} for name, path in files.items()}


def stage(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "kosmos_jax"


def test_every_stage_is_in_the_layer_table():
    stages = {stage(m) for m in graph()} - {"kosmos_jax"}
    assert stages <= set(LEVEL), f"add {sorted(stages - set(LEVEL))} to LAYERS"


def test_stages_import_only_from_stages_above():
    upward = []
    for module, imports in graph().items():
        here = stage(module)
        if here == "kosmos_jax":
            continue
        for target in imports:
            there = stage(target)
            if there != "kosmos_jax" and LEVEL[there] > LEVEL[here]:
                upward.append(f"{module} -> {target}")
    assert not upward, "imports from a later stage: " + ", ".join(sorted(upward))


def find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1 on the path, 2 done
    path: list[str] = []

    def visit(node):
        state[node] = 1
        path.append(node)
        for target in sorted(edges.get(node, ())):
            if state.get(target) == 1:
                return path[path.index(target):] + [target]
            if target not in state and (cycle := visit(target)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(edges):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_no_import_cycle_between_modules():
    edges = graph()
    # a package's __init__ re-exporting its own modules is not a cycle of the code
    edges = {m: {t for t in targets if not (m.startswith(t + ".") and t in edges)} for m, targets in edges.items()}
    assert find_cycle(edges) is None, " -> ".join(find_cycle(edges))


def test_no_import_cycle_between_packages():
    edges: dict[str, set[str]] = {}
    for module, imports in graph().items():
        edges.setdefault(stage(module), set()).update(stage(t) for t in imports if stage(t) != stage(module))
    assert find_cycle(edges) is None, " -> ".join(find_cycle(edges))


@pytest.mark.parametrize("edges, cycle", [({"a": {"b"}, "b": {"a"}}, True), ({"a": {"b"}, "b": {"c"}}, False)])
def test_the_cycle_finder_finds_cycles(edges, cycle):
    assert (find_cycle(edges) is not None) == cycle


def test_every_package_says_what_its_stage_takes_and_gives():
    for init in sorted(ROOT.glob("*/__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text()))
        assert doc and len(doc.splitlines()) >= 2, f"{init.relative_to(ROOT.parent)} needs a docstring of its stage"
