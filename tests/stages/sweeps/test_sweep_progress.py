"""The sweep's progress hears each job's count with that job in it: Snakemake says `Finished jobid` before the
`N of M steps` line, and a progress line made at the first said one job fewer (issue 55: "11 of 13 jobs" at the
end where the log said 13 of 13)."""

from __future__ import annotations

from mlnseq.sweeps import running

SNAKEMAKE_SAYS = """[Fri Dec  4 10:00:00 2026]
Finished jobid: 12 (Rule: eval)
12 of 13 steps (92%) done
Select jobs to execute...
[Fri Dec  4 10:00:05 2026]
Finished jobid: 0 (Rule: all)
13 of 13 steps (100%) done
Complete log(s): .snakemake/log/2026-12-04T100000.snakemake.log
"""


def test_progress_is_heard_after_each_count_with_the_count_in_it(tmp_path):
    heard = []
    reader = running.Reader(tmp_path / "sweep.log", lambda run: heard.append(run.jobs))
    for line in SNAKEMAKE_SAYS.splitlines(keepends=True):
        reader.line(line)
    reader.close(0)
    assert heard == [(12, 13), (13, 13)]
    assert (tmp_path / "sweep.log").read_text() == SNAKEMAKE_SAYS
