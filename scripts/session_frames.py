"""frames.csv of an omnicml log session, read and written by the session scripts
(drift_session.py, park_session.py): comment lines, the header and the rows as fields."""
import os


def read(session_dir):
    """(comment lines, header fields, rows as field lists) of session_dir/frames.csv."""
    with open(os.path.join(session_dir, "frames.csv")) as f:
        lines = f.read().splitlines()
    comments = [l for l in lines if l.startswith("#")]
    rows = [l for l in lines if l and not l.startswith("#")]
    return comments, rows[0].split(","), [r.split(",") for r in rows[1:]]


def write(session_dir, comments, head, rows):
    """Writes session_dir/frames.csv: the comment lines, the header, the rows (field lists)."""
    with open(os.path.join(session_dir, "frames.csv"), "w") as f:
        for l in comments:
            f.write(l + "\n")
        f.write(",".join(head) + "\n")
        for r in rows:
            f.write(",".join(r) + "\n")
