"""A simulated cluster of three Ray nodes on this machine (``ray.cluster_utils.Cluster``):
``--ray ADDRESS`` joins it, and learning and replaying give the bytes of one process."""

import json

import pytest
import ray
from click.testing import CliRunner
from ray.cluster_utils import Cluster  # noqa: E402

from slearn.cli import main
from slearn.jobs.cluster import ClusterError, ray_session  # noqa: E402
from slearn.jobs.distributed import RayReader  # noqa: E402
from slearn.jobs.learn import learn_files
from slearn.recorders.arm import ArmConfig, arm_spec, record_arm
from slearn.recorders.pointer import PointerConfig
from slearn.recorders.record_pointer import record_pointer


@pytest.fixture(scope="module")
def cluster():
    """A head that runs no task and two worker nodes of one CPU each; not joined here, so
    each command joins it by address as a user's would."""
    nodes = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "include_dashboard": False})
    for _ in range(2):
        nodes.add_node(num_cpus=1)
    nodes.wait_for_nodes()
    yield nodes.address
    nodes.shutdown()


@pytest.fixture(autouse=True)
def fixed_time(monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_pointer_logs_on_three_nodes_are_learned_and_replayed_as_in_one_process(cluster, tmp_path):
    logs = [record_pointer(PointerConfig(condition=c, trials=1500, seed=i, switch_trial=700),
                           tmp_path / f"p{i}.mcap").path for i, c in enumerate(["simple", "reversal", "error"])]
    one, many = tmp_path / "one.parquet", tmp_path / "many.parquet"
    assert cli("learn", *logs[:2], "-o", one, "-q").exit_code == 0
    result = cli("learn", *logs[:2], "-o", many, "-q", "--ray", cluster)
    assert result.exit_code == 0, result.output
    assert many.read_bytes() == one.read_bytes()
    reports = []
    for extra in ([], ["--ray", cluster]):
        replayed = cli("replay", one, logs[2], "--json", "-q", *extra)
        assert replayed.exit_code == 0, replayed.output
        reports.append({k: v for k, v in json.loads(replayed.stdout).items() if k != "speed"})
    assert reports[0] == reports[1] and reports[0]["totals"]["events"] > 1000
    assert not ray.is_initialized()  # the command left the cluster, which goes on running


def test_arm_logs_on_three_nodes_are_the_bytes_of_one_process(cluster, tmp_path):
    logs = [record_arm(ArmConfig(joints=2, trials=1500, seed=i), tmp_path / f"arm{i}.mcap").path
            for i in range(3)]
    learn_files(logs, tmp_path / "one.parquet", spec=arm_spec(2))
    with ray_session(address=cluster) as session:
        assert len([n for n in session.nodes() if n["Alive"]]) == 3
        learn_files(logs, tmp_path / "many.parquet", spec=arm_spec(2), reader=RayReader(session))
    assert (tmp_path / "many.parquet").read_bytes() == (tmp_path / "one.parquet").read_bytes()


def test_an_unreachable_cluster_is_one_line(tmp_path):
    with pytest.raises(ClusterError, match="cannot join the Ray cluster at 127.0.0.1:1: .*ray start --head"):
        with ray_session(address="127.0.0.1:1"):
            pass
