#!/usr/bin/env python3
"""package.xml declares every dependency the build finds, and the install script installs it.

Reads every CMakeLists.txt of the package (find_package, catkin's COMPONENTS,
find_library), maps each to its rosdep key, and checks that package.xml
declares the key and that scripts/install_deps.sh installs the Debian package
behind it, so that `rosdep install --from-paths` and the project's own setup
install the same things. This machine cannot reach rosdep's online index, so
the keys' meanings are the table below.

    package_dependencies.py PACKAGE_DIR
"""
import pathlib
import re
import sys
import xml.etree.ElementTree as ET

# CMake package (or library looked up with find_library) -> (rosdep key, Debian package).
# None: part of the toolchain, nothing to declare.
SYSTEM = {
    "Threads": None,
    "OpenMP": None,
    "Python3": ("python3-dev", "python3-dev"),
    "Eigen3": ("eigen", "libeigen3-dev"),
    "Ceres": ("libceres-dev", "libceres-dev"),
    "OpenCV": ("libopencv-dev", "libopencv-dev"),
    "faiss": ("libfaiss-dev", "libfaiss-dev"),
    "xxhash": ("libxxhash-dev", "libxxhash-dev"),
    "yaml-cpp": ("yaml-cpp", "libyaml-cpp-dev"),
    "pybind11": ("pybind11-dev", "pybind11-dev"),
    "rostest": ("rostest", "librostest-dev"),
    "cholmod": ("suitesparse", "libsuitesparse-dev"),
    "libblas.so.3": ("libopenblas-dev", "libopenblas0-pthread"),
}
# What the build uses without a CMake look-up: the Python module's numpy at
# run time, and catkin's gtest.
EXTRA = {"numpy": ("python3-numpy", "python3-numpy"), "gtest": ("gtest", "libgtest-dev")}
# Catkin packages come from Debian as these packages (the ones not named here
# come with ros-base-dev, which the install script installs).
CATKIN_DEBIAN = {
    "tf2_ros": "libtf2-ros-dev", "rosbag": "librosbag-dev", "cv_bridge": "libcv-bridge-dev",
    "image_transport": "libimage-transport-dev", "std_srvs": "libstd-srvs-dev",
    "diagnostic_updater": "libdiagnostic-updater-dev", "visualization_msgs": "libvisualization-msgs-dev",
    "dynamic_reconfigure": "libdynamic-reconfigure-config-init-mutex-dev",
    "message_generation": "ros-message-generation", "catkin": "catkin",
}


def cmake_dependencies(root):
    found = set()
    catkin = set()
    for path in root.rglob("CMakeLists.txt"):
        rel = path.relative_to(root)
        if rel.parts[0] in ("examples", "build") or rel.parts[0].startswith("build"):
            continue
        text = re.sub(r"#[^\n]*", "", path.read_text())
        for args in re.findall(r"find_package\s*\(([^)]*)\)", text):
            words = args.split()
            if words[0] == "catkin":
                catkin.update(w for w in words[words.index("COMPONENTS") + 1:] if w.isidentifier())
                found.add("catkin")
            else:
                found.add(words[0])
        for args in re.findall(r"find_(?:library|file)\s*\(([^)]*)\)", text):
            words = args.split()
            names = words[2:words.index("PATHS")] if "PATHS" in words else words[1:2]
            found.update(n for n in names if n != "NAMES")
    return found, catkin


def main():
    root = pathlib.Path(sys.argv[1]).resolve()
    declared = {}
    for element in ET.parse(root / "package.xml").getroot():
        if element.tag.endswith("depend"):
            declared.setdefault(element.text.strip(), set()).add(element.tag)
    installed = set(re.findall(r"[a-z0-9][a-z0-9.+-]+", re.sub(r"#[^\n]*", "",
                               (root / "scripts" / "install_deps.sh").read_text())))
    found, catkin = cmake_dependencies(root)
    problems = []
    keys = {}
    for name in sorted(found - {"catkin"}):
        if name not in SYSTEM:
            problems.append(f"CMake looks up '{name}', which has no rosdep key in {__file__}'s table")
        elif SYSTEM[name]:
            keys[SYSTEM[name][0]] = (name, SYSTEM[name][1])
    for name, (key, debian) in EXTRA.items():
        keys[key] = (name, debian)
    for component in sorted(catkin | {"catkin"}):
        keys[component] = (f"catkin component {component}", CATKIN_DEBIAN.get(component, "ros-base-dev"))
    for key, (what, debian) in sorted(keys.items()):
        if key not in declared:
            problems.append(f"{what}: package.xml declares no dependency on '{key}'")
        if debian not in installed:
            problems.append(f"{what}: scripts/install_deps.sh does not install '{debian}'")
    for key in sorted(set(declared) - set(keys) - {"message_runtime"}):
        problems.append(f"package.xml declares '{key}', which nothing in the build uses")
    for p in problems:
        print("package_dependencies:", p)
    print(f"package_dependencies: {len(keys)} dependencies checked, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
