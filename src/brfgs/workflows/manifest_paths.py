"""Where the scenes of a manifest read and write: every path resolved once (links followed), then
checked with sets of resolved paths and their parents, so a manifest of n scenes costs
O(n × path depth), not O(n²) comparisons.

The checks (each a :class:`UserError` naming the manifest and the field):

- the output root and every scene's output folder is a folder or can become one (not a file, nor
  below a file);
- no output folder is, lies inside or contains a scene folder (input data is never written to);
  the output root lies inside no scene folder;
- no two scenes share a name (ignoring case) or an output folder, and no output folder lies inside
  another scene's;
- a path whose links cannot be followed (a link loop, a folder that cannot be read) is named in one line.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from brfgs.errors import UserError


class Resolver:
    """Absolute, normalised paths with their links followed (as :meth:`Path.resolve`), each folder
    resolved once: resolving a path resolves its parent (cached) and follows its last component if
    it is a link. A loop, or a link that cannot be read, is a UserError naming ``file`` and the field."""

    def __init__(self, file: Path):
        self.file = file
        self._done: dict[str, str] = {}
        self._folder: dict[str, str | None] = {}

    def __call__(self, path: str | Path, field: str) -> str:
        try:
            return self._resolve(str(path))
        except OSError as exc:
            where = exc.filename or path
            raise UserError(f"cannot follow the links of {where} ({exc.strerror or exc})", file=self.file,
                            field=field) from None

    def _resolve(self, p: str) -> str:
        hit = self._done.get(p)
        if hit is not None:
            return hit
        parent, name = os.path.split(p)
        if not name:  # the root
            res = p
        else:
            joined = os.path.join(self._resolve(parent), name)
            res = joined
            if os.path.islink(joined):
                try:
                    res = os.path.realpath(joined, strict=True)
                except FileNotFoundError:  # a link to a path that does not exist (yet): as far as it goes
                    res = os.path.realpath(joined)
        self._done[p] = res
        return res

    def folder_problem(self, resolved: str) -> str | None:
        """Why ``resolved`` (a resolved path) cannot be an output folder, or None: it is a folder, or
        it does not exist and its nearest existing parent is a folder."""
        if resolved in self._folder:
            return self._folder[resolved]
        try:
            problem = None if stat.S_ISDIR(os.stat(resolved).st_mode) else f"{resolved} is a file, not a folder"
        except (FileNotFoundError, NotADirectoryError):
            parent = os.path.dirname(resolved)
            problem = None if parent == resolved else self.folder_problem(parent)
        except OSError as exc:
            problem = f"cannot read {resolved} ({exc.strerror or exc})"
        self._folder[resolved] = problem
        return problem


def _ancestors(p: str):
    """``p`` and every folder above it (resolved absolute paths)."""
    while True:
        yield p
        parent = os.path.dirname(p)
        if parent == p:
            return
        p = parent


def _within(p: str, paths: dict[str, int]) -> tuple[str, int] | None:
    """The first of ``paths`` (a path -> scene index map) that is ``p`` or a folder above it."""
    for a in _ancestors(p):
        i = paths.get(a)
        if i is not None:
            return a, i
    return None


def check_paths(scenes: list, out_root: Path, file: Path, resolve: Resolver) -> list[tuple[int, UserError]]:
    """Every conflict between the ``scenes`` (BatchScene-like, with ``index``: their 1-based place in
    the manifest) and the output root, as (scene index, UserError) in manifest order; index 0 for the
    output root. Raises at once when the output root itself cannot be resolved."""
    return _Check(scenes, out_root, file, resolve).problems()


class _Check:
    def __init__(self, scenes: list, out_root: Path, file: Path, resolve: Resolver):
        self.file, self.resolve, self.out_root = file, resolve, out_root
        self.root = resolve(out_root, "out")
        self.found: list[tuple[int, UserError]] = []
        self.scene_at: dict[str, int] = {}   # resolved scene folder -> first scene reading it
        self.out_at: dict[str, int] = {}     # resolved output folder -> first scene writing it
        self.outs: list[tuple[int, str]] = []
        self.nested: set[int] = set()          # scenes whose output folder and a scene folder nest (reported)
        self.by_index = {s.index: s for s in scenes}
        for s in scenes:
            try:
                self.scene_at.setdefault(resolve(s.scene, f"scene[{s.index}].scene"), s.index)
                out = resolve(s.out, f"scene[{s.index}].out")
            except UserError as exc:
                self.found.append((s.index, exc))
                continue
            self.outs.append((s.index, out))
            self.out_at.setdefault(out, s.index)

    def error(self, i: int, message: str, field: str) -> None:
        self.found.append((i, UserError(message, file=self.file, field=field)))

    def problems(self) -> list[tuple[int, UserError]]:
        hit = _within(self.root, self.scene_at)
        if hit:
            self.error(0, f"the output root {self.out_root} lies inside the scene folder {hit[0]} (scene "
                       f"'{self.by_index[hit[1]].name}'); input data is never written to", "out")
        problem = self.resolve.folder_problem(self.root)
        if problem:
            self.error(0, f"expected a folder: {problem}", "out")
        names: dict[str, int] = {}
        for i, out in self.outs:
            s = self.by_index[i]
            first = names.setdefault(s.name.casefold(), i)
            if first != i:
                self.error(i, f"two scenes are named {s.name!r} (scene[{first}] and scene[{i}]); give one a 'name'",
                           f"scene[{i}].name")
            self.output(i, out)
        for path, j in self.scene_at.items():  # a scene folder inside output folders
            for folder in _ancestors(path):
                i = self.out_at.get(folder)
                if i is not None and i not in self.nested:
                    self.nested.add(i)
                    self.error(i, f"the output folder {self.by_index[i].out} contains the scene folder "
                               f"{self.by_index[j].scene} (scene '{self.by_index[j].name}'); input data is never "
                               "written to", f"scene[{i}].out")
        return sorted(self.found, key=lambda p: p[0])

    def output(self, i: int, out: str) -> None:
        """The conflicts of scene ``i``'s output folder ``out`` (resolved)."""
        s, by_index = self.by_index[i], self.by_index
        hit = _within(out, self.scene_at)
        if hit:
            self.nested.add(i)
            self.error(i, f"the output folder {s.out} lies inside the scene folder {by_index[hit[1]].scene} (scene "
                       f"'{by_index[hit[1]].name}'); input data is never written to", f"scene[{i}].out")
        owner = self.out_at[out]
        if owner != i:
            self.error(i, f"scenes '{by_index[owner].name}' and '{s.name}' write into the same folder {s.out}",
                       f"scene[{i}].out")
        for parent in list(_ancestors(out))[1:]:
            j = self.out_at.get(parent)
            if j is not None:
                a, b = min(i, j), max(i, j)
                self.error(b, f"scenes '{by_index[a].name}' and '{by_index[b].name}' write into nested folders "
                           f"({by_index[a].out}, {by_index[b].out})", f"scene[{b}].out")
        problem = self.resolve.folder_problem(out)
        if problem:
            self.error(i, f"expected a folder: {problem}", f"scene[{i}].out")
