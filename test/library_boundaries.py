#!/usr/bin/env python3
"""Each library includes only its own internal headers and the public headers of the libraries below it.

The libraries are the folders of src/ (docs/architecture.md): a library's
internal headers sit beside its sources ("core/linalg/block_cholesky.h"),
its public ones under include/rotation_averaging/<library>/. This check reads
every #include "..." of src/ and include/ and fails on

  - a library (or a public header) including another library's internal
    header: what is shared belongs in include/ or behind a narrow interface;
  - an include that runs up the floors (the core including the front end, the
    front end including ROS, the ROS-free sim library including ROS);
  - a program of src/tools including any library's internal header (a tool is
    a thin main over public headers).

Tests and benchmarks are white-box (they test and measure internals) and are
not checked. The one exception is the back-end module: it is the core's own
code, a library of its own only so that CHOLMOD and Ceres load when a solve
first needs them, and it implements the core's plug-in interface.

    library_boundaries.py PACKAGE_DIR
"""
import pathlib
import re
import sys

# Library -> the libraries whose public headers it may include (itself too).
# "msgs" are the generated message, service and dynamic_reconfigure headers.
BELOW = {
    "util": {"util"},
    "core": {"util", "core"},
    "backends": {"util", "core", "backends"},
    "frontend": {"util", "core", "frontend"},
    "ros": {"util", "core", "frontend", "ros", "msgs"},
    "python": {"util", "core", "frontend", "python"},
    "sim": {"util", "core", "frontend", "sim"},
    "sim_ros": {"util", "core", "frontend", "sim", "sim_ros", "ros", "msgs"},
    "tools": {"util", "core", "frontend", "ros", "sim", "sim_ros", "msgs", "tools"},
}
# The core's plug-in interface, which the back-end module implements.
PLUGIN_INTERFACE = {"core/util/backends.h", "core/estimators/component_problem.h"}
# Files of src/sim that form rotation_averaging_sim_ros (src/sim/CMakeLists.txt).
SIM_ROS = {"demo_bag"}
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def library_of_source(rel):
    """The library a file of src/ belongs to."""
    library = rel.parts[1]
    if library == "sim" and pathlib.Path(rel.name).stem in SIM_ROS:
        return "sim_ros"
    return library


def library_of_public(parts):
    """The library a public header (parts after include/rotation_averaging/) belongs to."""
    if len(parts) == 1:
        return "msgs"
    if parts[0] == "sim" and pathlib.Path(parts[-1]).stem in SIM_ROS:
        return "sim_ros"
    return parts[0]


def check(root):
    src = root / "src"
    internal = {p.relative_to(src).as_posix(): library_of_source(p.relative_to(root))
                for p in src.rglob("*.h")}
    problems = []
    files = [(p, library_of_source(p.relative_to(root)), False) for p in src.rglob("*")
             if p.suffix in (".h", ".cpp") and p.relative_to(src).parts[0] not in ("benchmarks",)]
    files += [(p, library_of_public(p.relative_to(root / "include" / "rotation_averaging").parts), True)
              for p in (root / "include" / "rotation_averaging").rglob("*.h")]
    for path, library, public in files:
        rel = path.relative_to(root).as_posix()
        allowed = BELOW.get(library)
        if allowed is None:
            problems.append(f"{rel}: src/{library} is not a library this check knows; add it to BELOW")
            continue
        for name in INCLUDE.findall(path.read_text()):
            parts = name.split("/")
            if parts[0] == "rotation_averaging":
                owner = library_of_public(parts[1:])
                if owner not in allowed:
                    problems.append(f"{rel}: includes {name}: {library} may not depend on {owner}")
            elif name in internal:
                owner = internal[name]
                if public:
                    problems.append(f"{rel}: a public header includes {owner}'s internal header {name}")
                elif owner != library and not (library == "backends" and name in PLUGIN_INTERFACE):
                    problems.append(f"{rel}: includes {owner}'s internal header {name}; "
                                    "promote it to include/ or give it a narrow interface")
            elif not (path.parent / name).exists():
                problems.append(f"{rel}: includes \"{name}\", which is neither a public nor an internal header")
    return len(files), problems


def main():
    root = pathlib.Path(sys.argv[1]).resolve()
    count, problems = check(root)
    for p in problems:
        print("library_boundaries:", p)
    print(f"library_boundaries: {count} files checked, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
