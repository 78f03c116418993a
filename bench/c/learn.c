/* slearn's learning rule in plain C: the speed anchor of bench/bench_learn.py, which
 * checks that both build the same library, byte for byte.
 *
 * The rule (slearn/core/online.py, run_codes with learn=True): steps come encoded for views
 * (slearn/core/views.py): an action token per step and the (view, observation token) reports.
 * Each view's stream gets the step's action (all views), then its observation (a view
 * that did not report shows its last one again). Before an observation is appended, every
 * context of 1..K tokens just before it is looked up in a tree read backwards from the
 * view's root; the experts of slearn/core/mixer.py (frequent, recent and fresh outcome of each
 * context) are weighed by Hedge with sleeping experts and a spread bound (every log-weight
 * halved when the view's rounds reach a power of two), the view's persistence specialist
 * (its last reading again) weighed against the chosen expert's answer per context length, a Bernoulli
 * CUSUM watches the trusted frequency expert (each prediction's expected miss rate from
 * PPM-C's estimate in its context, calibrated by the hits of its cell: the octaves of the
 * context's count and of the odds against a miss), and every context counts one more
 * occurrence of the observation (count, last_seen, fresh count with lazy epoch reset).
 *
 * Hash tables hold record ids; a record's key is (parent, token) for nodes and
 * (owner, outcome) for entries, found as slearn/core/hashtable.py finds them: an entry from
 * the hash of its pair, a node from the hash of its path (slearn/core/context_tree.py).
 * A view's ring of tokens is a power of two wide (slearn/core/views.py). Capacities are
 * given by the caller (no growth), so ids and every number match slearn's.
 *
 * With -DPREFETCH, the lookups ask the CPU for their memory ahead, where slearn's kernel
 * does (context_tree.fetch_nodes, fetch_entry_slots, fetch_entries; slearn only for tables
 * past context_tree.FETCH_SLOTS, as the benchmark's are): the anchor for slearn as it runs.
 * Without, the plain loop.
 *
 * Build: cc -O2 -ffp-contract=off -shared -fPIC -o liblearn.so learn.c -lm [-DPREFETCH]
 */
#include <math.h>
#include <stdlib.h>
#include <stdint.h>

#ifdef PREFETCH
#define FETCH(address) __builtin_prefetch((address), 0, 3)
#else
#define FETCH(address) ((void)0)
#endif

#define EMPTY (-1)
#define FREQUENT 0
#define RECENT 1
#define FRESH 2
#define KINDS 3

typedef struct {
    int32_t *parent, *token, *first, *best, *newest, *fresh_best, *epoch, *node_slots;
    int32_t *owner, *outcome, *next, *entry_slots;
    int64_t *count, *last_seen, *fresh, *size;
    int64_t node_slot_count, entry_slot_count;
} tree_t;

/* The high 32 bits of a multiplicative hash, scaled to the table's size (any size). */
static int64_t home(int64_t a, int64_t b, int64_t n) {
    uint64_t key = ((uint64_t)a << 32) | (uint64_t)(uint32_t)b;
    uint64_t h = (key * 0x9E3779B97F4A7C15ULL) >> 32;
    return (int64_t)((h * (uint64_t)n) >> 32);
}

/* A node's path hash from its parent's (context_tree.path_hash and root_path). */
static uint64_t path_hash(uint64_t h, int32_t tok) {
    uint64_t x = (h ^ ((uint64_t)tok + 1)) * 0x9E3779B97F4A7C15ULL;
    return x ^ (x >> 32);
}

static uint64_t root_path(int32_t root) { return path_hash(0x243F6A8885A308D3ULL, root); }

/* The slot of a path hash (hashtable.scaled). */
static int64_t slot_of(uint64_t h, int64_t n) { return (int64_t)(((h >> 32) * (uint64_t)n) >> 32); }

static int32_t child_or_add(tree_t *t, int32_t node, int32_t tok, uint64_t h) {
    int64_t s = slot_of(h, t->node_slot_count);
    for (;;) {
        int32_t r = t->node_slots[s];
        if (r == EMPTY) break;
        if (t->parent[r] == node && t->token[r] == tok) return r;
        if (++s == t->node_slot_count) s = 0;
    }
    int32_t fresh = (int32_t)t->size[0];
    t->parent[fresh] = node;
    t->token[fresh] = tok;
    t->first[fresh] = t->best[fresh] = t->newest[fresh] = t->fresh_best[fresh] = -1;
    t->epoch[fresh] = 0;
    t->node_slots[s] = fresh;
    t->size[0] = fresh + 1;
    return fresh;
}

static int32_t entry_or_add(tree_t *t, int32_t node, int32_t out) {
    int64_t s = home(node, out, t->entry_slot_count);
    for (;;) {
        int32_t r = t->entry_slots[s];
        if (r == EMPTY) break;
        if (t->owner[r] == node && t->outcome[r] == out) return r;
        if (++s == t->entry_slot_count) s = 0;
    }
    int32_t e = (int32_t)t->size[1];
    t->owner[e] = node;
    t->outcome[e] = out;
    t->count[e] = t->last_seen[e] = t->fresh[e] = 0;
    t->next[e] = t->first[node];
    t->first[node] = e;
    t->entry_slots[s] = e;
    t->size[1] = e + 1;
    return e;
}

static void refresh(tree_t *t, int32_t node, int32_t current) {
    if (t->epoch[node] == current) return;
    for (int32_t e = t->first[node]; e != -1; e = t->next[e]) t->fresh[e] = 0;
    t->fresh_best[node] = -1;
    t->epoch[node] = current;
}

static void credit(tree_t *t, int32_t e, int32_t node, int64_t clock) {
    t->count[e] += 1;
    t->last_seen[e] = clock;
    t->fresh[e] += 1;
    int32_t b = t->best[node];
    if (b == -1 || t->count[e] >= t->count[b]) t->best[node] = e;
    t->newest[node] = e;
    b = t->fresh_best[node];
    if (b == -1 || t->fresh[e] >= t->fresh[b]) t->fresh_best[node] = e;
}

static int32_t find_entry(const tree_t *t, int32_t node, int32_t out) {
    int64_t s = home(node, out, t->entry_slot_count);
    for (;;) {
        int32_t r = t->entry_slots[s];
        if (r == EMPTY) return -1;
        if (t->owner[r] == node && t->outcome[r] == out) return r;
        if (++s == t->entry_slot_count) s = 0;
    }
}

/* The reports since the change the test dates, counted into the new epoch (online.recount). */
#define PAST 256
static void recount(tree_t *t, const int32_t *past_node, const int32_t *past_outcome, int64_t filled,
                    int64_t *since, int32_t ep) {
    int64_t n = *since < filled ? *since : filled;
    if (n > PAST) n = PAST;
    for (int64_t i = filled - n; i < filled; i++) {
        int32_t nd = past_node[i % PAST], x = past_outcome[i % PAST];
        while (t->parent[nd] >= 0) {
            refresh(t, nd, ep);
            int32_t e = find_entry(t, nd, x);
            if (e >= 0) {
                t->fresh[e] += 1;
                int32_t b = t->fresh_best[nd];
                if (b == -1 || t->fresh[e] >= t->fresh[b]) t->fresh_best[nd] = e;
            }
            nd = t->parent[nd];
        }
    }
    *since = 0;
}

/* --- the mixer (slearn/core/mixer.py) ---------------------------------------------------- */

static void update(double *w, int64_t *rounds, const int32_t *cand, int n, int K, int32_t truth,
                   double beta, double floor_) {
    if (n == 0) return;
    int64_t t = ++*rounds;
    if (t > 1 && (t & (t - 1)) == 0)  /* a power of two: every log-weight halves */
        for (int i = 0; i < K * KINDS; i++) w[i] = sqrt(w[i]);
    /* An expert whose context is missing says what its longest shorter twin found says. */
    double before = 0.0, after = 0.0;
    for (int kind = 0; kind < KINDS; kind++) {
        int32_t said = -1;
        for (int k = 1; k <= K; k++) {
            if (k <= n && cand[k * KINDS + kind] >= 0) said = cand[k * KINDS + kind];
            if (said < 0) continue;
            double *x = &w[(k - 1) * KINDS + kind];
            before += *x;
            if (said != truth) *x *= beta;
            after += *x;
        }
    }
    if (after <= 0.0) return;
    double ratio = before / after;
    for (int kind = 0; kind < KINDS; kind++) {
        int32_t said = -1;
        for (int k = 1; k <= K; k++) {
            if (k <= n && cand[k * KINDS + kind] >= 0) said = cand[k * KINDS + kind];
            if (said >= 0) w[(k - 1) * KINDS + kind] *= ratio;
        }
    }
    double leader = 0.0;
    for (int i = 0; i < K * KINDS; i++) leader = w[i] > leader ? w[i] : leader;
    double scale = 1.0 / leader;
    for (int i = 0; i < K * KINDS; i++) {
        double x = w[i] * scale;
        w[i] = (0.0 < x && x < floor_) ? floor_ : x;
    }
}

/* The expert that speaks (mixer.select): the awake expert of largest weight, a missing
 * context's expert lending its weight to its shorter twins; then the longest context of
 * the leader's kind less than one mistake behind it and not tied with it. */
static void select_expert(const double *w, const int32_t *cand, int n, int K, double beta, double same,
                          int *k_out, int *kind_out) {
    double best_w = -1.0, lent[KINDS] = {0.0};
    int best_k = 0, best_kind = 0;
    for (int k = K; k >= 1; k--)
        for (int kind = 0; kind < KINDS; kind++) {
            double x = w[(k - 1) * KINDS + kind] > lent[kind] ? w[(k - 1) * KINDS + kind] : lent[kind];
            if (k <= n && cand[k * KINDS + kind] >= 0) {
                if (x > best_w) best_w = x, best_k = k, best_kind = kind;
            } else {
                lent[kind] = x;
            }
        }
    for (int k = n < K ? n : K; k > best_k; k--) {
        double x = w[(k - 1) * KINDS + best_kind];
        if (cand[k * KINDS + best_kind] >= 0 && best_w * beta < x && x < best_w * (1.0 - same)) {
            best_k = k;
            break;
        }
    }
    *k_out = best_k, *kind_out = best_kind;
}

/* The persistence specialists (mixer.update_persist), after update counted round t. */
static void update_persist(double *p, int64_t t, int K, int length, int32_t said, int32_t last, int32_t truth,
                           double beta, double floor_) {
    if (t > 1 && (t & (t - 1)) == 0)
        for (int k = 0; k < K; k++) p[k] = sqrt(p[k]);
    if (last < 0 || length <= 0) return;
    double x = p[length - 1];
    if (last == truth && said != truth) {
        x = x / beta;
        if (x > 1.0 / floor_) x = 1.0 / floor_;
    } else if (last != truth && said == truth) {
        x = x * beta;
        if (x < floor_) x = floor_;
    }
    p[length - 1] = x;
}

static int trusted_length(const double *w, const int32_t *cand, int n, int32_t epoch) {
    int kind = epoch == 0 ? FREQUENT : FRESH;
    double best = -1.0;
    int out = 0;
    for (int k = 1; k <= n; k++)
        if (cand[k * KINDS + kind] >= 0 && w[(k - 1) * KINDS + kind] >= best) {
            best = w[(k - 1) * KINDS + kind];
            out = k;
        }
    return out;
}

static void weight_sums(const tree_t *t, const int64_t *weight, int32_t node,
                        int64_t *total, int64_t *distinct) {
    *total = 0, *distinct = 0;
    for (int32_t f = t->first[node]; f != -1; f = t->next[f])
        if (weight[f] > 0) *total += weight[f], (*distinct)++;
}

static int calibration_cell(int64_t c, int64_t total, int64_t distinct, int octaves) {
    int count_octave = 0, odds_octave = 0;
    while (count_octave < octaves - 1 && (total >> (count_octave + 1)) > 0) count_octave++;
    int64_t whole = total + distinct, miss = whole - c;
    while (odds_octave < octaves - 1 && (miss << (odds_octave + 1)) <= whole) odds_octave++;
    return count_octave * octaves + odds_octave;
}

static int detect(double *w, double *det, int64_t *cal, int K, int hit, int64_t c, int64_t total,
                  int64_t distinct, double threshold, double below, double prior, int octaves) {
    if (total <= 0) return 0;
    int64_t *cell = &cal[2 * calibration_cell(c, total, distinct, octaves)];
    double share = (double)c / (double)(total + distinct);
    double evidence = prior + (double)total;
    double p_hit = ((double)cell[0] + evidence * share) / ((double)cell[1] + evidence);
    cell[0] += hit ? 1 : 0;
    cell[1] += 1;
    double q0 = 1.0 - p_hit;
    double q1 = 0.5 * (1.0 + q0);
    double step = hit ? log((1.0 - q1) / (1.0 - q0)) : log(q1 / q0);
    det[0] = det[0] + step > 0.0 ? det[0] + step : 0.0;
    det[1] += hit ? 0.0 : 1.0;
    det[2] += 1.0;
    if (det[0] < threshold) return 0;
    det[0] = det[1] = det[2] = 0.0;
    for (int k = 0; k < K; k++) {  /* each length's best weight: fresh counts first, all-time just below */
        double a = w[k * KINDS + FREQUENT], r = w[k * KINDS + RECENT], b = w[k * KINDS + FRESH];
        double best = a > r ? a : r;
        best = best > b ? best : b;
        w[k * KINDS + FRESH] = best;
        w[k * KINDS + FREQUENT] = best * below;
    }
    return 1;
}

/* --- the step loop ------------------------------------------------------------------ */

typedef struct {
    int32_t n_views, K, has_actions, empty_action, empty_observation;
    double beta, floor_, threshold, below, prior;
    int32_t octaves;
    double same;
} params_t;

int64_t slearn_learn(tree_t *t, double *weights, double *detector, int32_t *epoch, int64_t *calibration,
                     int64_t *rounds, double *persist, int32_t *recent, int64_t *filled, int32_t *held, const int32_t *root,
                     const int32_t *action, const int64_t *offsets, const int32_t *view,
                     const int32_t *token, int64_t n_steps, int64_t clock, const params_t *p) {
    int K = p->K;
    int W = 1;  /* the ring's width: the power of two at or above K */
    while (W < K) W *= 2;
    const int64_t M = W - 1;
    int32_t nodes[256];
    uint64_t hashes[256];
    int32_t cand[257 * KINDS];
    /* The episode's latest reports per view (online.Past): this call is one episode. */
    int32_t *past_node = calloc((size_t)p->n_views * PAST, sizeof(int32_t));
    int32_t *past_outcome = calloc((size_t)p->n_views * PAST, sizeof(int32_t));
    int64_t *past_filled = calloc((size_t)p->n_views, sizeof(int64_t));
    int64_t *since = calloc((size_t)p->n_views, sizeof(int64_t));
    for (int64_t step = 0; step < n_steps; step++) {
        int32_t a = action[step];
        int push_action = p->has_actions && (step > 0 || a != p->empty_action);
        if (push_action)
            for (int v = 0; v < p->n_views; v++) recent[v * W + (filled[v] & M)] = a, filled[v]++;
        for (int64_t r = offsets[step]; r < offsets[step + 1]; r++) {
            int32_t v = view[r], x = token[r];
            int depth = filled[v] < K ? (int)filled[v] : K;
            if (depth > 0) {
                int32_t ep = epoch[v], node = root[v];
                uint64_t h = root_path(node);
                int n = 0, m = 0;
                for (int k = 1; k <= depth; k++) {
                    h = path_hash(h, recent[v * W + ((filled[v] - k) & M)]);
                    hashes[k] = h;
                    FETCH(&t->node_slots[slot_of(hashes[k], t->node_slot_count)]);
                }
#ifdef PREFETCH
                for (int k = 1; k <= depth; k++) {
                    int32_t found = t->node_slots[slot_of(hashes[k], t->node_slot_count)];
                    if (found >= 0) {
                        FETCH(&t->parent[found]); FETCH(&t->token[found]);
                        FETCH(&t->first[found]); FETCH(&t->best[found]);
                    }
                }
#endif
                for (int k = 1; k <= depth; k++) {
                    int32_t tok = recent[v * W + ((filled[v] - k) & M)];
                    node = child_or_add(t, node, tok, hashes[k]);
                    nodes[k] = node;
                    n = k;
                }
                for (int k = 1; k <= n; k++) {
                    int32_t nd = nodes[k];
                    if (t->first[nd] == -1) break;
                    int32_t fb = t->fresh_best[nd];
                    int current = t->epoch[nd] == ep && fb != -1;
                    cand[k * KINDS + FREQUENT] = t->outcome[t->best[nd]];
                    cand[k * KINDS + RECENT] = t->outcome[t->newest[nd]];
                    cand[k * KINDS + FRESH] = (ep > 0 && current) ? t->outcome[fb] : -1;
                    m = k;
                }
                for (int k = 1; k <= n; k++) FETCH(&t->entry_slots[home(nodes[k], x, t->entry_slot_count)]);
                double *w = &weights[(int64_t)v * K * KINDS];
                int k_sel = 0, kind = 0;
                if (m > 0) select_expert(w, cand, m, K, p->beta, p->same, &k_sel, &kind);
                update(w, &rounds[v], cand, m, K, x, p->beta, p->floor_);
                if (m > 0)
                    update_persist(&persist[(int64_t)v * K], rounds[v], K, k_sel, cand[k_sel * KINDS + kind], held[v],
                                   x, p->beta, p->floor_);
                int kt = trusted_length(w, cand, m, ep), alarm = 0;
                if (kt > 0) {
                    int32_t nd = nodes[kt], b = ep > 0 ? t->fresh_best[nd] : t->best[nd];
                    const int64_t *weight = ep > 0 ? t->fresh : t->count;
                    int64_t total, distinct;
                    weight_sums(t, weight, nd, &total, &distinct);
                    alarm = detect(w, &detector[v * 3], &calibration[(int64_t)v * 2 * p->octaves * p->octaves], K,
                                   t->outcome[b] == x, weight[b], total, distinct, p->threshold, p->below,
                                   p->prior, p->octaves);
                }
                if (alarm) {
                    epoch[v] += 1;
                    recount(t, &past_node[v * PAST], &past_outcome[v * PAST], past_filled[v], &since[v], epoch[v]);
                } else if (detector[v * 3] == 0.0) {
                    since[v] = 0;
                } else {
                    since[v]++;
                }
                ep = epoch[v];
#ifdef PREFETCH
                for (int k = 1; k <= n; k++) {
                    int32_t e = t->entry_slots[home(nodes[k], x, t->entry_slot_count)];
                    if (e >= 0) {
                        FETCH(&t->owner[e]); FETCH(&t->outcome[e]); FETCH(&t->count[e]);
                        FETCH(&t->last_seen[e]); FETCH(&t->fresh[e]);
                    }
                }
#endif
                for (int k = 1; k <= n; k++) {
                    int32_t nd = nodes[k];
                    refresh(t, nd, ep);
                    credit(t, entry_or_add(t, nd, x), nd, clock);
                }
                if (n > 0) {
                    past_node[v * PAST + past_filled[v] % PAST] = nodes[n];
                    past_outcome[v * PAST + past_filled[v] % PAST] = x;
                    past_filled[v]++;
                }
            }
            recent[v * W + (filled[v] & M)] = x;
            filled[v]++;
            held[v] = x;
        }
        if (push_action) {
            int64_t r = offsets[step];
            for (int v = 0; v < p->n_views; v++) {
                if (r < offsets[step + 1] && view[r] == v) { r++; continue; }
                recent[v * W + (filled[v] & M)] = held[v] != -1 ? held[v] : p->empty_observation;
                filled[v]++;
            }
        }
        clock++;
    }
    free(past_node); free(past_outcome); free(past_filled); free(since);
    return clock;
}
