"""The guarded server's door (serving/guarded.py): the names it answers to, and a Host header read."""

from __future__ import annotations

from mlnseq.serving.guarded import own_names, split_host


def test_the_hosts_a_server_answers_to():
    assert own_names("127.0.0.1") == {"127.0.0.1", "localhost", "::1"}
    assert own_names("10.1.2.3") == {"10.1.2.3"}
    assert split_host("localhost:8750") == ("localhost", 8750)
    assert split_host("[::1]:80") == ("::1", 80)
    assert split_host("evil.example") == ("evil.example", None)
    assert split_host("a:b") == ("a", -1)
