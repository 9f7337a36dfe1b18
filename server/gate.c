/* gate.c — the render gate (see gate.h). */
#include "gate.h"

void gate_init(struct gate *g, unsigned slots, unsigned queue)
{
    pthread_mutex_init(&g->lock, NULL);
    pthread_cond_init(&g->cond, NULL);
    g->slots = slots ? slots : 1;
    g->queue = queue;
    g->running = g->waiting = 0;
    g->closed = false;
}

void gate_destroy(struct gate *g)
{
    pthread_cond_destroy(&g->cond);
    pthread_mutex_destroy(&g->lock);
}

bool gate_enter(struct gate *g, bool bounded, struct err *err)
{
    pthread_mutex_lock(&g->lock);
    if (g->closed) {
        pthread_mutex_unlock(&g->lock);
        return err_set(err, ERR_BUSY, NULL, "the daemon is shutting down");
    }
    if (g->running >= g->slots && bounded && g->waiting >= g->queue) {
        unsigned w = g->waiting;
        pthread_mutex_unlock(&g->lock);
        return err_set(err, ERR_BUSY, NULL, "the render queue is full (%u waiting)", w);
    }
    g->waiting++;
    while (g->running >= g->slots && !g->closed) pthread_cond_wait(&g->cond, &g->lock);
    g->waiting--;
    if (g->closed) {
        pthread_mutex_unlock(&g->lock);
        return err_set(err, ERR_BUSY, NULL, "the daemon is shutting down");
    }
    g->running++;
    pthread_mutex_unlock(&g->lock);
    return true;
}

void gate_leave(struct gate *g)
{
    pthread_mutex_lock(&g->lock);
    g->running--;
    pthread_cond_broadcast(&g->cond);
    pthread_mutex_unlock(&g->lock);
}

void gate_close(struct gate *g)
{
    pthread_mutex_lock(&g->lock);
    g->closed = true;
    pthread_cond_broadcast(&g->cond);
    pthread_mutex_unlock(&g->lock);
}

unsigned gate_waiting(struct gate *g)
{
    pthread_mutex_lock(&g->lock);
    unsigned w = g->waiting;
    pthread_mutex_unlock(&g->lock);
    return w;
}
