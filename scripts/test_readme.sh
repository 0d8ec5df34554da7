#!/usr/bin/env bash
# Runs every ```bash block of README.md as a user would after
# `bash scripts/setup.sh`, from the repository root, each in a fresh bash with
# `set -e`: a block that fails fails this script. A block may say otherwise
# with an HTML comment on the line before it:
#   <!-- readme-test: skip REASON -->      not run here; REASON says where it is run
#   <!-- readme-test: long-running N -->   each line starts a program that runs until
#                                          stopped (a node): it must still be running
#                                          after N s, against a master of its own
#   bash scripts/test_readme.sh      (after scripts/setup.sh)
source "$(dirname "$0")/common.sh"
ROOT=$(pwd)
WORK=$ROOT/$BUILD/test_readme
rm -rf "$WORK" && mkdir -p "$WORK"
/usr/bin/python3 - README.md "$WORK" <<'PY'
import pathlib, re, sys
text = pathlib.Path(sys.argv[1]).read_text()
out = pathlib.Path(sys.argv[2])
blocks = re.findall(r"(?:<!-- readme-test: ([^>]*?) -->\n)?```bash\n(.*?)```", text, re.S)
for n, (mode, body) in enumerate(blocks, 1):
    (out / f"{n:02d}.sh").write_text(body)
    (out / f"{n:02d}.mode").write_text(mode.strip())
print(f"test_readme: {len(blocks)} bash blocks in README.md")
PY
export ROS_MASTER_URI=http://127.0.0.1:11392 ROS_HOME=$WORK/ros_home ROS_LOG_DIR=$WORK/ros_log
status=0
for script in "$WORK"/*.sh; do
  n=$(basename "$script" .sh)
  mode=$(cat "$WORK/$n.mode")
  first=$(grep -v '^#' "$script" | head -1)
  case "$mode" in
    skip*)
      echo "test_readme: block $n ($first) not run here: ${mode#skip }"
      continue ;;
    long-running*)
      seconds=${mode#long-running }
      rosmaster --core -p 11392 > "$WORK/$n.master.log" 2>&1 &
      master=$!
      sleep 2
      i=0
      while IFS= read -r line; do
        case "$line" in ''|'#'*) continue ;; esac
        i=$((i + 1))
        (set +u; source devel/setup.bash; exec bash -c "$line") > "$WORK/$n.$i.log" 2>&1 &
        pid=$!
        sleep "$seconds"
        if kill -0 "$pid" 2>/dev/null; then
          echo "test_readme: block $n: '$line' still running after ${seconds} s"
          pkill -INT -P "$pid" 2>/dev/null || true; kill -INT "$pid" 2>/dev/null || true
          wait "$pid" 2>/dev/null || true
        else
          echo "test_readme: block $n: '$line' exited within ${seconds} s:" >&2
          tail -20 "$WORK/$n.$i.log" >&2
          status=1
        fi
      done < "$script"
      kill "$master" 2>/dev/null; wait "$master" 2>/dev/null || true
      continue ;;
  esac
  if (set +u; source devel/setup.bash; set -e; source "$script") > "$WORK/$n.log" 2>&1; then
    echo "test_readme: block $n ($first) ran"
  else
    echo "test_readme: block $n ($first) FAILED:" >&2
    tail -30 "$WORK/$n.log" >&2
    status=1
  fi
done
exit $status
