"""tests/PROOFS.md, the list of what each Docker-level test proves, is current."""

from __future__ import annotations

from tests import proofs


def test_the_list_of_proofs_is_current() -> None:
    assert proofs.PROOFS.read_text() == proofs.render(), (
        "tests/PROOFS.md is not current: run `python -m tests.proofs` and review its diff "
        "(a proof that disappeared must be proven elsewhere)")


def test_a_proof_is_the_first_sentence_of_the_docstring_else_the_name() -> None:
    assert proofs.first_sentence("The dry run shows it. Then more.\n") == "The dry run shows it."
    assert proofs.first_sentence("BUILDER names a builder:\n dev and run") == (
        "BUILDER names a builder: dev and run.")
    assert proofs.as_sentence("test_pushed_run_image_runs") == "Pushed run image runs."
