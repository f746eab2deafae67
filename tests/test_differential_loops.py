"""Differential tests of the queue loops (LoopString, LoopInt, LoopDouble, LoopBool) against
BehaviorTree.CPP v4 itself (``behaviortreepy``), with the harness of
``test_differential_btcpp.py``: every node's status, the root's status and the status changes
after every tick, the integer entries, and here also the ``value`` each loop writes.

Literal queues, blackboard queues (set by a script inside the tree: BT.CPP converts the text
into its shared queue when the entry is typed by the loop's port), child RUNNING / SUCCESS /
FAILURE / SKIPPED sequences, every ``if_empty``, and halts in the middle of a loop.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest
import test_differential_btcpp as differential
from test_differential_btcpp import BLACKBOARD, VARS, TreeGen, check, diff, doc

STR = {"v": "string"}

# name -> (body, outputs read after each tick, subtrees T1, T2...)
CASES: dict[str, tuple] = {
    # literal queues
    "literal_instant_child": (
        '<LoopString name="l" queue="A-01-1;A-02-1;A-03-1" value="{v}">'
        '<AlwaysSuccess name="x"/></LoopString>',
        STR,
    ),
    "literal_running_child": (
        '<LoopString name="l" queue="a;b;c" value="{v}"><Scripted name="x_RRS"/></LoopString>',
        STR,
    ),
    "literal_child_fails_then_restarts": (
        '<LoopString name="l" queue="a;b;c" value="{v}"><Scripted name="x_RSF"/></LoopString>',
        STR,
    ),
    "literal_sync_child": (
        '<LoopString name="l" queue="a;b" value="{v}"><ScriptedSync name="x_SSF"/></LoopString>',
        STR,
    ),
    "literal_empty_items_and_trailing_separator": (
        '<LoopString name="l" queue="a;;b;" value="{v}"><AlwaysSuccess name="x"/></LoopString>',
        STR,
    ),
    "skipped_child": (
        '<LoopString name="l" queue="a;b;c" value="{v}">'
        '<AlwaysSuccess name="x" _skipIf="v == \'b\'"/></LoopString>',
        STR,
    ),
    "loop_int_writes_an_int_entry": (
        '<LoopInt name="l" queue="3;1;2" value="{c0}"><Script name="a" code="c1 += c0"/></LoopInt>',
        {},
    ),
    "loop_double": (
        '<LoopDouble name="l" queue="0.5;1.25;-2" value="{v}"><Scripted name="x_RS"/></LoopDouble>',
        {"v": "double"},
    ),
    "loop_bool_child_reads_value": (
        '<LoopBool name="l" queue="true;1;false;0" value="{v}">'
        '<ScriptCondition name="x" code="v"/></LoopBool>',
        {"v": "bool"},
    ),
    "no_value_port": (
        '<LoopInt name="l" queue="1;2"><Scripted name="x_RS"/></LoopInt>',
        {},
    ),
    # if_empty
    "empty_success": ('<LoopString name="l" queue=""><AlwaysSuccess name="x"/></LoopString>', {}),
    "empty_failure": (
        '<LoopString name="l" queue="" if_empty="FAILURE"><AlwaysSuccess name="x"/></LoopString>',
        {},
    ),
    "empty_skipped_in_sequence": (
        '<Sequence name="s"><LoopString name="l" queue="" if_empty="SKIPPED">'
        '<AlwaysSuccess name="x"/></LoopString><Scripted name="y_RS"/></Sequence>',
        {},
    ),
    "empty_running_waits": (
        '<LoopInt name="l" queue="" if_empty="RUNNING"><AlwaysSuccess name="x"/></LoopInt>',
        {},
    ),
    "exhausted_then_failure": (
        '<LoopInt name="l" queue="1;2" if_empty="FAILURE" value="{c0}">'
        '<Scripted name="x_RS"/></LoopInt>',
        {},
    ),
    # blackboard queues
    "blackboard_queue_refilled_by_a_script": (
        '<Sequence name="s"><Script name="f" code="q := \'a;b;c\'"/>'
        '<LoopString name="l" queue="{q}" value="{v}"><Scripted name="x_RS"/></LoopString>'
        "</Sequence>",
        STR,
    ),
    "blackboard_queue_consumed_across_runs": (
        '<Sequence name="s"><RunOnce name="o"><Script name="f" code="q := \'a;b\'"/>'
        '</RunOnce><LoopString name="l" queue="{q}" value="{v}" if_empty="FAILURE">'
        '<AlwaysSuccess name="x"/></LoopString></Sequence>',
        STR,
    ),
    "blackboard_queue_child_failure_keeps_the_rest": (
        '<Sequence name="s"><RunOnce name="o"><Script name="f" code="q := \'1;2;3;4\'"/>'
        '</RunOnce><LoopInt name="l" queue="{q}" value="{c0}">'
        '<ScriptedSync name="x_SF"/></LoopInt></Sequence>',
        {},
    ),
    "blackboard_queue_through_subtree": (
        '<Sequence name="s"><Script name="f" code="q := \'a;b\'"/>'
        '<SubTree name="st" ID="T1" items="{q}" item="{v}"/></Sequence>',
        STR,
        '<LoopString name="l" queue="{items}" value="{item}"><Scripted name="x_RS"/></LoopString>',
    ),
    "blackboard_queue_set_by_set_blackboard": (
        '<Sequence name="s"><SetBlackboard name="f" output_key="q" value="a;b"/>'
        '<LoopString name="l" queue="{q}" value="{v}"><AlwaysSuccess name="x"/></LoopString>'
        "</Sequence>",
        STR,
    ),
    "two_loops_share_one_queue": (
        '<Sequence name="s"><RunOnce name="o"><Script name="f" code="q := \'1;2;3;4;5\'"/>'
        '</RunOnce><Parallel name="p" success_count="2">'
        '<LoopInt name="l1" queue="{q}" value="{c0}"><Scripted name="x_RS"/></LoopInt>'
        '<LoopInt name="l2" queue="{q}" value="{c1}"><Scripted name="y_RRS"/></LoopInt>'
        "</Parallel></Sequence>",
        {},
    ),
    "nested_loops": (
        '<LoopInt name="l1" queue="1;2" value="{c0}"><LoopInt name="l2" queue="5;6" '
        'value="{c1}"><Script name="a" code="c2 += c0 * c1"/></LoopInt></LoopInt>',
        {},
    ),
    # halted in the middle of a loop
    "halted_literal_restarts": (
        '<ReactiveSequence name="r"><ScriptedSync name="g_SSSF"/>'
        '<LoopString name="l" queue="a;b;c" value="{v}"><Scripted name="x_RS"/></LoopString>'
        "</ReactiveSequence>",
        STR,
    ),
    "halted_blackboard_queue_goes_on": (
        '<Sequence name="s"><RunOnce name="o"><Script name="f" code="q := \'a;b;c;d\'"/>'
        '</RunOnce><ReactiveSequence name="r"><ScriptedSync name="g_SSSF"/>'
        '<LoopString name="l" queue="{q}" value="{v}"><Scripted name="x_RS"/></LoopString>'
        "</ReactiveSequence></Sequence>",
        STR,
    ),
    "while_halts_the_loop": (
        '<Parallel name="p" success_count="2"><LoopInt name="l" queue="1;2;3;4;5" '
        'value="{c1}" _while="c0 &lt; 3" _onHalted="c2 += 1"><Scripted name="x_RS"/></LoopInt>'
        + differential.KRUF_COUNT
        + "</Parallel>",
        {},
    ),
    "repeat_around_a_loop": (
        '<Repeat name="r" num_cycles="2"><LoopInt name="l" queue="1;2" value="{c0}">'
        '<Script name="a" code="c1 += c0"/></LoopInt></Repeat>',
        {},
    ),
}


@pytest.fixture(scope="module", autouse=True)
def _close_peer():
    """Close the BT.CPP worker process this module shares with test_differential_btcpp."""
    yield
    if differential._PEER:
        differential._PEER.pop().close()


@pytest.mark.parametrize("case", sorted(CASES))
def test_loop_matches_btcpp(case: str) -> None:
    body, outputs, *subtrees = CASES[case]
    check(doc(body, *subtrees), ticks=12, blackboard=dict(BLACKBOARD), outputs=outputs)


class LoopTreeGen(TreeGen):
    """Random trees as in test_differential_btcpp, with queue loops among the decorators.

    ``LoopInt`` writes its ``value`` into an integer entry the scripts read (BT.CPP refuses
    other loops' values in integer entries); the other loops write no value.
    """

    def decorator(self, depth: int) -> ET.Element:
        r = self.rng
        if r.random() < 0.5:
            return super().decorator(depth)
        tag = r.choice(("LoopInt", "LoopInt", "LoopString", "LoopDouble", "LoopBool"))
        el = self._new(tag)
        n = r.choice((0, 1, 2, 3))
        items = {
            "LoopInt": lambda: str(r.randint(0, 3)),
            "LoopString": lambda: r.choice(("a", "b", "")),
            "LoopDouble": lambda: r.choice(("0.5", "-1", "2")),
            "LoopBool": lambda: r.choice(("true", "false")),
        }[tag]
        el.set(
            "queue", ";".join(items() for _ in range(n)) + (";" if n and r.random() < 0.2 else "")
        )
        if tag == "LoopInt" and r.random() < 0.8:
            el.set("value", "{" + r.choice(VARS) + "}")
        if r.random() < 0.5:
            el.set("if_empty", r.choice(("SUCCESS", "FAILURE", "SKIPPED")))
        el.append(self.node(depth + 1))
        return el


LOOP_SEEDS = range(50_000, 50_150)


def test_random_trees_with_loops_match_btcpp() -> None:
    failures = []
    for seed in LOOP_SEEDS:
        xml = LoopTreeGen(seed).xml()
        problem = diff(xml)
        if problem is not None:
            failures.append(f"seed {seed}: {problem}\n{xml}")
    assert not failures, f"{len(failures)} trees differ; first:\n{failures[0]}"


def test_random_trees_use_every_loop() -> None:
    seen = {el.tag for seed in LOOP_SEEDS for el in ET.fromstring(LoopTreeGen(seed).xml()).iter()}
    assert {"LoopInt", "LoopString", "LoopDouble", "LoopBool"} <= seen
