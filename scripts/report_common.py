"""What the results writers (scripts/*_report.py) share: the header line every results file starts its text with,
and values read from the summaries the tools print."""
import datetime
import os
import re


def cores():
    """The processors this process may run on, as nproc counts them."""
    return len(os.sched_getaffinity(0))


def reproduce_line(command, extra=""):
    """"Reproduce with: `command`. Generated <UTC time> UTC on a N-core machine<extra>." """
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M")
    return "Reproduce with: `%s`. Generated %s UTC on a %d-core machine%s." % (command, now, cores(), extra)


def values(text, pattern):
    """The first group of every line of `text` matching `pattern` (multiline), in order."""
    return [m.group(1) for m in re.finditer(pattern, text, re.M)]


def first(text, pattern, default=""):
    """The first group of the first line of `text` matching `pattern` (multiline); `default` if none does."""
    match = re.search(pattern, text, re.M)
    return match.group(1) if match else default


def value(text, pattern, default=""):
    """The first group of the lines matching `pattern`, one per line; `default` if none matches."""
    found = values(text, pattern)
    return "\n".join(found) if found else default


def view_errors(path):
    """The per-view errors of a scores file (rotavg eval --per-view), in its order: (name, error as printed);
    none if the file is missing."""
    errors = []
    if not os.path.exists(path):
        return errors
    for line in open(path).read().splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0] == "view":
            errors.append((parts[1], parts[2]))
    return errors
