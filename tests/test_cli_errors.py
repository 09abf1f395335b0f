"""Bad options fail before any work, in one line that names the option the user typed: a path
that cannot be written (tried, not inferred: root passes every permission check, yet cannot
write in /proc), a file an option names that is not there, options that contradict each
other, and a value a record refuses, named by its option, not by the record's field."""

import pytest

from host.cli import main
from host.cli.render import in_user_terms
from tests.test_cli import EXAMPLE


def fails(capsys, *flags: str) -> str:
    """The one line `meshtrace render EXAMPLE FLAGS` prints as it fails (exit 2)."""
    code = main(["render", str(EXAMPLE), "--width", "8", "--height", "8", "--quiet", *flags])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "Traceback" not in err[0] and "Errno" not in err[0]
    return err[0]


@pytest.mark.parametrize("flag", ["-o", "--stats", "--float"])
def test_a_folder_that_exists_but_takes_no_files_fails_first(capsys, flag, tmp_path):
    suffix = {"-o": "o.png", "--stats": "s.json", "--float": "f.pfm"}[flag]
    extra = ["-o", str(tmp_path / "a.png")] if flag != "-o" else []
    line = fails(capsys, *extra, flag, f"/proc/{suffix}")
    assert line.startswith(f"host: {flag} /proc/{suffix}: cannot write there")
    assert not list(tmp_path.iterdir())  # nothing rendered, nothing left behind


@pytest.mark.parametrize("flag", ["--camera", "--cluster", "--settings", "--secret-file"])
def test_a_missing_input_file_is_named_with_its_option(capsys, flag, tmp_path):
    missing = tmp_path / "nothing.here"
    assert fails(capsys, flag, str(missing)) == f"host: {flag} {missing}: no such file"


def test_mesh_and_cluster_together_are_refused(capsys, tmp_path):
    cluster = tmp_path / "c.txt"
    cluster.write_text("0 0 127.0.0.1:9\n")
    line = fails(capsys, "--mesh", "2x2", "--cluster", str(cluster))
    assert line == "host: --mesh 2x2 and --cluster: choose one (the cluster file gives the mesh)"


@pytest.mark.parametrize(
    ("flags", "said"),
    [(["--spp", "-3"], "--spp -3: must be"), (["--width", "-5"], "--width -5: must be")],
)
def test_a_refused_value_is_named_by_its_option(capsys, flags, said):
    line = fails(capsys, *flags)
    assert said in line and "ImageSpec" not in line


def test_record_fields_become_options_in_any_case():
    assert in_user_terms("IMAGESPEC.SPP = 0: too few") == "--spp 0: too few"
    assert in_user_terms("EngineSpec.threads must be whole") == "--threads must be whole"


def test_a_local_node_that_dies_before_listening_is_named_in_one_line(tmp_path, capsys):
    # Killed before it printed `listening` (or exiting on its own), a local node gave a
    # RuntimeError traceback; now a MeshError names the node and how it ended, and the CLI
    # prints it as one line, every other node stopped.
    import pytest

    from host.run.errors import MeshError
    from host.run.localmesh import LocalMesh

    def killed(i):
        return ["sh", "-c", "kill -9 $$", "--"] if i == 1 else []

    with pytest.raises(MeshError, match=r"local node 1 \(pid \d+\) was killed by signal 9"):
        with LocalMesh(2, wrap=killed):
            pass
    with pytest.raises(MeshError, match="local node 0 .* exited with code 1 before"):
        with LocalMesh(1, module="no_such_module_here"):
            pass
