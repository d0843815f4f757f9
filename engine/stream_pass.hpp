#pragma once
// A stream pass: the flow-graph shape every pipeline stage of qemflow is built from.
//
//   read (I/O thread) ──► [sequencer ──► decode (compute, serial, in order)] ──► transform (compute,
//   concurrent) ──► sequencer ──► sink (compute, serial, in order)
//
// Node contract
// - read(item, lease): runs on the dedicated I/O thread, one call at a time, in order.
//   It fills `item` with the next unit (a batch, a frame) sized to what `lease` holds
//   (it may shrink the lease to what it used) and returns false, leaving the item
//   empty, at the end of the stream. It must only read (no compression, no parsing
//   beyond what the reader library does).
// - Backpressure: before every read, the pass asks the governor for a lease of
//   [min_item_bytes, max_item_bytes]; if less than min is free, the read is parked
//   (the I/O thread keeps serving writes) until a lease is released. Each item
//   carries its lease through transform and sink and releases it when it is dropped.
//   So memory, not a count, bounds how far the reader runs ahead, and no item is ever
//   dropped (unlike limiter_node).
// - max_in_flight caps the items between read and the end of sink (a count, on top
//   of the bytes): reading far ahead buys nothing once every thread is busy.
// - transform(item, lease) and sink(item, lease) may split() part of the item's lease
//   off to hand it, with the buffer it covers, to an I/O task (e.g. a write).
// - decode(item, lease), optional: runs on a compute thread, one item at a time in read
//   order, before transform. Parsing that must walk the stream in order (a record cut
//   by an item's end, carried to the next) lives here, so read only moves bytes.
// - transform(item): runs on compute threads, up to transform_concurrency at once, in
//   any order unless `ordered` (then one at a time in read order, via sequencer_node).
//   Decompression and format conversion belong here.
// - sink(item): runs on compute threads, one at a time, in read order (a sequencer
//   behind the concurrent transforms), so state that many items update (a spill, an
//   output cursor) ends the same on every run: records filed in the same order, output
//   bytes the same (DESIGN.md §3, guarantee 1). Items that finish early wait there with
//   their leases, so memory still bounds how far the pass runs ahead.
// - No node body may wait for memory: a stage takes its working set (spill buffers,
//   windows) before the pass, from one reservation (Lease::split), so no job ever holds
//   part of its memory while waiting for more and jobs sharing a governor cannot
//   deadlock. Bodies may wait for the I/O thread (it never waits for compute).
// - Cancel / failure: once the job has stopped, read ends the stream and transform and
//   sink skip their work, so the graph drains quickly; run_stream_pass then rethrows
//   the error. The whole graph is wired in run_stream_pass, below.
#include <oneapi/tbb/flow_graph.h>

#include <functional>
#include <memory>
#include <mutex>
#include <utility>

#include "engine/job.hpp"

namespace qemflow::engine {

template <class Item>
struct StreamPass {
  const char* stage = "stage";          // stage name for the report
  const char* read_name = "read";       // span names (string literals)
  const char* transform_name = "transform";
  const char* sink_name = "sink";
  std::string owner = "reader";         // governor owner of the items' leases
  uint64_t min_item_bytes = 1 << 20;
  uint64_t max_item_bytes = 1 << 20;
  std::function<bool(Item&, Lease&)> read;
  std::function<void(Item&, Lease&)> decode;     // optional
  std::function<void(Item&, Lease&)> transform;  // optional
  size_t transform_concurrency = tbb::flow::unlimited;
  bool ordered = false;
  std::function<void(Item&, Lease&)> sink;       // optional
  int max_in_flight = 16;
  // Optional: the exact lease the next item needs (e.g. a frame's size); replaces
  // min/max_item_bytes. Called on the I/O thread just before read.
  std::function<uint64_t()> next_item_bytes;
  // Optional: called on the I/O thread when a read is parked for memory (after the
  // governor took the wake-up request), e.g. to free buffers kept for later items.
  std::function<void()> parked_for_memory;
};

namespace detail {
template <class Item>
struct Envelope {
  Lease lease;
  uint64_t seq = 0;
  Item item;
};
}  // namespace detail

template <class Item>
void run_stream_pass(Job& job, const StreamPass<Item>& pass) {
  using Env = detail::Envelope<Item>;
  using Msg = std::shared_ptr<Env>;
  namespace flow = tbb::flow;
  if (!pass.next_item_bytes) job.governor().require_fits(job.owner(pass.owner), pass.min_item_bytes);
  StageStats& stage = job.stage(pass.stage);
  // The pass's nodes count their own work (their spans); the calling thread only waits,
  // or runs those nodes, while a span around the pass (an epoch's gather) is open.
  Waiting waiting;
  job.arena().execute([&] {
    flow::graph graph;
    using Source = flow::async_node<flow::continue_msg, Msg>;
    using Gateway = typename Source::gateway_type;

    // The pump is a chain of I/O tasks, one per item; it lives until the last task.
    struct Pump {
      Gateway* gateway = nullptr;
      uint64_t seq = 0;
      bool done = false;
      std::function<void()> step;
      std::mutex mutex;  // guards the two below
      int in_flight = 0;
      bool parked = false;  // waiting for an item to leave (count limit)
    };
    auto pump = std::make_shared<Pump>();
    std::weak_ptr<Pump> weak = pump;
    const std::string owner = job.owner(pass.owner);
    pump->step = [&job, &pass, &stage, weak, owner] {
      auto self = weak.lock();
      if (!self || self->done) return;
      auto finish = [&] {
        self->done = true;
        self->gateway->release_wait();
      };
      try {
        if (job.stopped()) return finish();
        {
          std::lock_guard lock(self->mutex);
          if (self->in_flight >= pass.max_in_flight) {
            self->parked = true;
            return;
          }
        }
        uint64_t min_bytes = pass.min_item_bytes, max_bytes = pass.max_item_bytes;
        if (pass.next_item_bytes) min_bytes = max_bytes = pass.next_item_bytes();
        Lease lease = job.governor().acquire_or_notify(
            owner, min_bytes, max_bytes, [&job, weak, &pass] {
              if (auto s = weak.lock()) job.io().submit(pass.read_name, s->step, {});
            });
        if (!lease) {  // parked until memory is released
          if (pass.parked_for_memory) pass.parked_for_memory();
          return;
        }
        auto env = std::make_shared<Env>();
        env->seq = self->seq++;
        bool more = pass.read(env->item, lease);
        if (!more || job.stopped()) return finish();
        env->lease = std::move(lease);
        ++stage.items;
        {
          std::lock_guard lock(self->mutex);
          ++self->in_flight;
        }
        self->gateway->try_put(env);
        job.io().submit(pass.read_name, self->step, {});
      } catch (...) {
        job.fail(std::current_exception());
        finish();
      }
    };

    Source source(graph, flow::serial, [&](const flow::continue_msg&, Gateway& gateway) {
      gateway.reserve_wait();
      pump->gateway = &gateway;
      job.io().submit(pass.read_name, pump->step, {});
    });
    auto guarded = [&job](const char* name, const std::function<void(Item&, Lease&)>& body,
                          Env& env) {
      if (!body || job.stopped()) return;
      Span span(&job.trace(), &job.activity(), name);
      try {
        body(env.item, env.lease);
      } catch (...) {
        job.fail(std::current_exception());
      }
    };
    auto consume = [&](const Msg& msg) {
      guarded(pass.sink_name, pass.sink, *msg);
      msg->item = Item{};  // the item's memory goes before its lease does
      msg->lease.release();
      bool resume = false;
      {
        std::lock_guard lock(pump->mutex);
        --pump->in_flight;
        resume = std::exchange(pump->parked, false);
      }
      if (resume) job.io().submit(pass.read_name, pump->step, {});
    };
    // A serial function_node may start a newly arrived message before a queued one,
    // so an ordered pass runs transform and sink in the one node behind the sequencer.
    flow::function_node<Msg, Msg> transform(
        graph, pass.ordered ? size_t{flow::serial} : size_t{pass.transform_concurrency}, [&](const Msg& msg) {
          if (pass.ordered) guarded("decode", pass.decode, *msg);
          guarded(pass.transform_name, pass.transform, *msg);
          if (pass.ordered) consume(msg);
          return msg;
        });
    // Rejecting, like decode below: it pulls the next item in read order when it is free.
    flow::function_node<Msg, flow::continue_msg, flow::rejecting> sink(graph, flow::serial, [&](const Msg& msg) {
      consume(msg);
      return flow::continue_msg();
    });
    flow::sequencer_node<Msg> sink_order(graph, [](const Msg& msg) { return size_t(msg->seq); });
    flow::sequencer_node<Msg> sequencer(graph, [](const Msg& msg) { return size_t(msg->seq); });
    // The decode node rejects while busy, so it pulls the sequencer's next item only
    // when it is free: strictly one at a time, in read order.
    flow::function_node<Msg, Msg, flow::rejecting> decode(graph, flow::serial, [&](const Msg& msg) {
      guarded("decode", pass.decode, *msg);
      return msg;
    });
    if (pass.ordered) {
      flow::make_edge(source, sequencer);
      flow::make_edge(sequencer, transform);
    } else if (pass.decode) {
      flow::make_edge(source, sequencer);
      flow::make_edge(sequencer, decode);
      flow::make_edge(decode, transform);
      flow::make_edge(transform, sink_order);
      flow::make_edge(sink_order, sink);
    } else {
      flow::make_edge(source, transform);
      flow::make_edge(transform, sink_order);
      flow::make_edge(sink_order, sink);
    }
    source.try_put(flow::continue_msg());
    graph.wait_for_all();
    // The last parked step (if any) finds the pump gone and does nothing.
  });
  job.check();
}

}  // namespace qemflow::engine
